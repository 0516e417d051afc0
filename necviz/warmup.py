"""Warm-up before a run's first packet: every kernel the control path needs is compiled, or loaded from
Numba's on-disk cache, before the source delivers anything, so start-up is never counted as command
latency (and a live camera's first packets do not wait for a compiler).

:func:`warm_up_lanes` feeds a short synthetic stream (:func:`warm_up_stream`: events outside and inside
exposures, a well-exposed frame, a saturated one) through *copies* of each lane's controller and passive
P-TEDI estimator and through a throwaway telemetry lane, so the lanes themselves start untouched. The
pipeline (:class:`necviz.pipeline.Pipeline`) calls it, and each observer's ``warm_up``, before it asks the
source for its first packet. Cost: loading ~30 cached kernels takes ~0.3-1 s on a cold process; a warm
process (kernels already loaded) pays a few milliseconds.
"""

from __future__ import annotations

import copy

import numpy as np

from necviz.core.errors import NecvizError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame


def warm_up_stream(sensor, t0_us: int = 1_000) -> list:
    """A few milliseconds of a plausible stream on ``sensor``: event batches before, inside and after three
    exposures (and batches of one event, whose field views Numba types as contiguous), their markers and
    frames (mid-grey, over-exposed, mid-grey: the saturation paths run too)."""
    rng = np.random.default_rng(0)
    h, w = sensor.height, sensor.width

    def events(t_a: int, t_b: int, n: int = 64) -> np.ndarray:
        ev = np.empty(n, EVENT_DTYPE)
        ev["t"] = np.sort(rng.integers(t_a, t_b, n))
        ev["x"] = rng.integers(0, w, n)
        ev["y"] = rng.integers(0, h, n)
        ev["p"] = rng.choice(np.array([-1, 1], np.int8), n)
        return ev

    grey = np.full((h, w), 120, np.uint8)
    grey[:, : w // 2] = 90
    bright = np.full((h, w), 255, np.uint8)
    out: list = []
    t = t0_us
    for seq, img in enumerate((grey, bright, grey)):
        s, e = t + 500, t + 2_500
        out += [
            EventBatch(events(t, s)),
            ExposureMarker(s, "start"),
            EventBatch(events(s, e)),
            ExposureMarker(e, "end"),
        ]
        # a one-event batch too: its field views are contiguous, a separate Numba signature
        out += [
            Frame(img, s, e, 1.0, seq),
            EventBatch(events(e, e + 1_000)),
            EventBatch(events(e + 1_000, e + 1_001, 1)),
        ]
        t = e + 1_001
    return out


def warm_up_lanes(lanes, sensor) -> None:
    """Run :func:`warm_up_stream` through copies of every lane's controller and passive estimator, and a
    throwaway telemetry lane (the diagnosis of a saturated frame included). Errors are ignored: a
    controller that refuses the synthetic stream simply warms up on the real one."""
    from necviz.telemetry import LaneTelemetry

    stream = warm_up_stream(sensor)
    for ln in lanes:
        try:
            ctrl = copy.deepcopy(ln.controller)
            passive = copy.deepcopy(ln.passive) if ln.passive is not None else None
        except Exception:  # noqa: BLE001 - an uncopyable custom controller: nothing to warm
            continue
        tel = LaneTelemetry("warm-up")
        est = passive if passive is not None else ctrl.estimator
        try:
            for pk in stream:
                if isinstance(pk, ExposureMarker) and pk.kind == "start" and est is not None:
                    tel.exposure_start(pk.t_us, est)
                fe = passive.feed(pk) if passive is not None else None
                cmd = ctrl.feed(pk)
                if cmd is not None:
                    tel.command(0.0, cmd)
                if isinstance(pk, Frame):
                    fe = fe if fe is not None else ctrl.last_frame_estimate
                    tel.frame(pk, fe, est.min_valid_fraction if est is not None else 0.5)
                if est is not None and est.ready and isinstance(pk, EventBatch) and len(pk):
                    est.predict(pk.t_last_us)
        except NecvizError:
            continue


__all__ = ["warm_up_lanes", "warm_up_stream"]
