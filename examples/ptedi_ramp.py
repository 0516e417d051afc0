#!/usr/bin/env python
"""P-TEDI on a synthetic irradiance ramp: event-propagated prediction vs the closed-form truth.

A small 64x48 textured scene brightens log-linearly: ln L(t) rises by ``--ramp-ln`` (default 2.0)
over ``--ramp-ms`` (default 500 ms), starting at 100 ms. Ideal DVS events are placed at the exact
threshold-crossing times; frames (every 20 ms, one fixed exposure) are exact exposure averages
through the DAVIS346-like camera response. Everything goes through ``interleave`` into a
``PeripheralEstimator``, which re-anchors on each frame and propagates with events in between.
Printed: predicted ln P vs the true ln of the mean irradiance at a few times, the value of the
last frame alone, and the largest prediction error (it should stay well below c/2 = 0.13).

usage: python examples/ptedi_ramp.py [--ramp-ln 2.0] [--ramp-ms 500] [--plot ramp.png]
"""

import argparse
import math

import numpy as np

from necviz.core import (
    EVENT_DTYPE,
    EventBatch,
    Frame,
    PeripheralEstimator,
    SensorGeometry,
    TediParams,
    default_davis346,
)
from necviz.core.stream import interleave

C_ON, C_OFF = 0.26, 0.24
RAMP_START_US, FRAME_PERIOD_US = 100_000, 20_000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ramp-ln", type=float, default=2.0, help="rise of ln L over the ramp (> 0, at most 2.5)")
    ap.add_argument("--ramp-ms", type=float, default=500.0, help="ramp duration in ms (> 0)")
    ap.add_argument("--plot", metavar="PNG", help="also draw truth, prediction and frames into this image")
    args = ap.parse_args()
    if not (0 < args.ramp_ln <= 2.5 and args.ramp_ms > 0):
        ap.error("need 0 < --ramp-ln <= 2.5 (the frames' usable range) and --ramp-ms > 0")
    delta_ln, ramp_us = args.ramp_ln, args.ramp_ms * 1e3
    sensor, crf = SensorGeometry(64, 48), default_davis346()
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width]
    log_l0 = 5.0 + 0.2 * np.sin(xx / 5.0) * np.cos(yy / 4.0) + 0.1 * np.where((xx // 8 + yy // 8) % 2, 1, -1)
    end_us = int(RAMP_START_US + ramp_us + 100_000)

    def ramp_ln(t_us):  # ln L(t) - ln L(0), the same for every pixel
        return delta_ln * np.clip((np.asarray(t_us, float) - RAMP_START_US) / ramp_us, 0.0, 1.0)

    def true_log_mean(t_us):  # ln of the sensor-mean irradiance: what the frames (Eq. 15) measure
        return math.log(np.exp(log_l0).mean()) + float(ramp_ln(t_us))

    # ideal events: pixel reference sits `phase` below its start level; ON event k at level k*c - phase
    phase = rng.uniform(0.0, C_ON, sensor.num_pixels)
    n_ev = np.floor((delta_ln + phase) / C_ON).astype(np.int64)
    pix = np.repeat(np.arange(sensor.num_pixels), n_ev)
    k = np.arange(pix.size) - np.repeat(np.cumsum(n_ev) - n_ev, n_ev) + 1
    t_cross = RAMP_START_US + ramp_us * (k * C_ON - phase[pix]) / delta_ln
    order = np.argsort(t_cross, kind="stable")
    events = np.zeros(pix.size, EVENT_DTYPE)
    events["t"] = np.ceil(t_cross[order] - 1e-9)  # an event belongs to the first whole µs after its crossing
    events["x"], events["y"], events["p"] = pix[order] % sensor.width, pix[order] // sensor.width, 1

    def ramp_integral(s, e):  # ∫_s^e exp(ramp_ln(t)) dt in closed form (before / on / after the ramp)
        t1, total = RAMP_START_US + ramp_us, max(0.0, min(e, RAMP_START_US) - s)
        lo, hi = max(s, RAMP_START_US), min(e, t1)
        if hi > lo:
            total += ramp_us / delta_ln * (math.exp(float(ramp_ln(hi))) - math.exp(float(ramp_ln(lo))))
        return total + max(0.0, e - max(s, t1)) * math.exp(delta_ln)

    # one exposure for the whole run: the brightest pixel at the end of the ramp reads 230 DN (below the knee)
    exposure_us = int(math.exp(crf.log_exposure(230) - log_l0.max() - delta_ln) * 1e6)
    frames = []
    for i, s in enumerate(range(1_000, end_us - exposure_us, FRAME_PERIOD_US)):
        e = s + exposure_us
        log_h = log_l0 + math.log(ramp_integral(s, e) / exposure_us) + math.log(exposure_us / 1e6)
        frames.append(Frame(np.clip(np.rint(crf.intensity(log_h)), 0, 255).astype(np.uint8), s, e, 1.0, i))

    est = PeripheralEstimator(sensor, TediParams(C_ON, C_OFF), crf)
    trace, frame_ln = [], math.nan  # (t µs, predicted ln P, last frame's ln Pbar, true ln)
    for packet in interleave(events, frames, batch_us=5_000):
        if (fe := est.feed(packet)) is not None:
            frame_ln = float(fe.log_mean_irradiance[0])
        elif isinstance(packet, EventBatch) and est.ready:
            t = est.last_event_us
            trace.append((t, est.predict(t), frame_ln, true_log_mean(t)))
    tr = np.array(trace)
    err = np.abs(tr[:, 1] - tr[:, 3])
    print(
        f"{sensor.width}x{sensor.height} px, ramp +{delta_ln:g} ln over {args.ramp_ms:g} ms, {events.size} events, "
        f"{len(frames)} frames at {exposure_us} µs"
    )
    print(f"{'t ms':>7s} {'true ln':>8s} {'P-TEDI ln':>9s} {'error':>7s} {'last frame ln':>13s}")
    for tq in np.linspace(RAMP_START_US, RAMP_START_US + ramp_us, 6):
        i = min(int(np.searchsorted(tr[:, 0], tq)), len(tr) - 1)
        t, pred, fr, truth = tr[i]
        print(f"{t / 1e3:7.1f} {truth:8.3f} {pred:9.3f} {pred - truth:+7.3f} {fr:13.3f}")
    print(
        f"max |error| over {len(tr)} predictions: {err.max():.4f} ln (frames alone: "
        f"{np.abs(tr[:, 2] - tr[:, 3]).max():.4f} ln)"
    )
    if args.plot:
        draw(args.plot, tr, end_us)


def draw(path: str, tr: np.ndarray, end_us: int) -> None:
    """Truth (green), P-TEDI (red) and the last frame's value (blue) vs time, drawn with OpenCV."""
    import cv2

    w, h, m = 640, 360, 40
    img = np.full((h, w, 3), 255, np.uint8)
    lo, hi = tr[:, 1:].min() - 0.1, tr[:, 1:].max() + 0.1
    px = lambda t, v: (int(m + (w - 2 * m) * t / end_us), int(h - m - (h - 2 * m) * (v - lo) / (hi - lo)))  # noqa: E731
    for col, bgr in ((3, (0, 160, 0)), (2, (200, 0, 0)), (1, (0, 0, 220))):
        pts = np.array([px(t, v) for t, v in zip(tr[:, 0], tr[:, col], strict=True)], np.int32)
        cv2.polylines(img, [pts], False, bgr, 1, cv2.LINE_AA)
    cv2.rectangle(img, (m, m), (w - m, h - m), (0, 0, 0), 1)
    cv2.putText(
        img,
        f"ln L {lo:.1f}..{hi:.1f} over 0..{end_us / 1e3:.0f} ms: true (green), P-TEDI (red), last frame (blue)",
        (m, m - 12),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.4,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    if not cv2.imwrite(path, img):
        raise SystemExit(f"could not write {path}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
