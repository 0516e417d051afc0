"""``necviz bench pipeline``: the whole dashboard path at the DAVIS346's full event rate.

A synthetic 346x260 stream (default 12 Mev/s, 50 fps frames, 10 s) goes through the pipeline
exactly as ``necviz live`` runs it: packets -> P-TEDI -> NEC -> commands back to the source, and
-> the Rerun sink writing a file with the default decimation. The stream is generated before the
clock starts (its arrays are sliced, not copied, while timing); frames follow the commanded
exposure (closed loop) from a cache of pre-rendered images.

Each configuration runs ``repeats`` times; the median run is reported. Reported: the real-time factor (stream duration / wall time) with logging on and with logging
off (same stream, same run), the control latency p50/p99 (packet out of the source -> command
back to it, processing time) and what the sink dropped or decimated.

The scene: ln irradiance follows a triangle wave (1 ln unit up over 200 ms, then down), so
P-TEDI's prediction moves and NEC keeps commanding between frames. Event polarities are drawn
so the ON/OFF balance integrates to that wave with c_on = 0.26, c_off = 0.24.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from necviz.bench.timing import machine, write_result
from necviz.core.control import CameraLimits, make_controller
from necviz.core.crf import US_PER_S, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import DAVIS346, DAVIS_EVENT_RATE_MAX
from necviz.drivers.source import CameraInfo, Source, route
from necviz.progress import output

C_ON, C_OFF = 0.26, 0.24
RISE_US = 200_000  # half period of the triangle wave
SWING = 1.0  # ln units per half period
BASE_LOG = math.log(2_000.0)  # ln irradiance at the bottom of the wave


def log_irradiance(t_us: np.ndarray | float):
    """The synthetic scene: a triangle wave in ln irradiance."""
    ph = np.mod(np.asarray(t_us, dtype=np.float64), 2 * RISE_US) / RISE_US
    return BASE_LOG + SWING * np.where(ph < 1.0, ph, 2.0 - ph)


def make_events(duration_s: float, rate_mev_s: float, seed: int = 0) -> np.ndarray:
    """Events at ``rate`` spread evenly in time; ON fraction per half period integrates to the wave."""
    n = int(duration_s * rate_mev_s * 1e6)
    rng = np.random.default_rng(seed)
    ev = np.empty(n, EVENT_DTYPE)
    ev["t"] = (np.arange(n, dtype=np.int64) * int(duration_s * 1e6)) // max(n, 1)
    ev["x"] = rng.integers(0, DAVIS346.width, n, dtype=np.uint16)
    ev["y"] = rng.integers(0, DAVIS346.height, n, dtype=np.uint16)
    per_half = rate_mev_s * 1e6 * RISE_US / 1e6
    npix = DAVIS346.width * DAVIS346.height
    p_up = (SWING * npix + C_OFF * per_half) / ((C_ON + C_OFF) * per_half)
    p_down = (-SWING * npix + C_OFF * per_half) / ((C_ON + C_OFF) * per_half)
    rising = np.mod(ev["t"], 2 * RISE_US) < RISE_US
    ev["p"] = np.where(rng.random(n) < np.where(rising, p_up, p_down), 1, -1).astype(np.int8)
    return ev


class SyntheticStream(Source):
    """A closed-loop source over pre-generated events: 1 ms batches, frames at ``fps``.

    Exposure commands apply at the next exposure start (at most the frame period minus 1 ms).
    """

    cameras = ("camera",)
    camera_info = CameraInfo(event_rate_max=DAVIS_EVENT_RATE_MAX)

    def __init__(
        self,
        events: np.ndarray,
        duration_s: float,
        fps: float = 50.0,
        batch_us: int = 1_000,
        exposure_us: float = 2_000.0,
    ):
        self.sensor = DAVIS346
        self.events = events
        self.duration_us = int(duration_s * 1e6)
        self.period_us = int(round(1e6 / fps))
        self.batch_us = int(batch_us)
        self.exposure_us, self.gain = float(exposure_us), 1.0
        self._pending = None
        self.commands = 0
        crf = default_davis346()
        self._crf = crf
        rng = np.random.default_rng(1)
        texture = rng.integers(-12, 13, DAVIS346.shape).astype(np.int16)
        self._images = [np.clip(texture + z, 0, 255).astype(np.uint8) for z in range(256)]
        grid = np.arange(0, self.duration_us + self.batch_us, self.batch_us, dtype=np.int64)
        self._cuts = np.searchsorted(events["t"], grid, side="left")

    def set_exposure(
        self, camera: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None:
        self._pending = (float(exposure_us), float(gain))
        self.commands += 1

    def packets(self):
        return route("camera", self)

    def close(self) -> None:
        pass

    def warm_up(self) -> None:
        pass

    def _image(self, s: int, e: int) -> np.ndarray:
        lp = float(log_irradiance(0.5 * (s + e)))
        z = float(self._crf.intensity(lp + math.log((e - s) / US_PER_S) + math.log(self.gain)))
        return self._images[int(min(max(round(z), 0), 255))]

    def __iter__(self):
        ev, cuts, b = self.events, self._cuts, self.batch_us
        next_start = 1_000
        exp_end = None
        exp_start = 0
        seq = 0
        i = 0
        for k in range(len(cuts) - 1):
            t0 = k * b
            t1 = t0 + b
            lo, hi = int(cuts[k]), int(cuts[k + 1])
            # markers inside [t0, t1): split the batch there
            while True:
                if exp_end is None and next_start < t1:
                    cut = int(np.searchsorted(ev["t"][lo:hi], next_start)) + lo
                    if cut > lo:
                        yield EventBatch(ev[lo:cut])
                    lo = cut
                    if self._pending is not None:
                        self.exposure_us, self.gain = self._pending
                        self._pending = None
                    exp_start = next_start
                    exp_len = int(min(max(self.exposure_us, 10.0), self.period_us - 1_000))
                    exp_end = exp_start + exp_len
                    next_start += self.period_us
                    yield ExposureMarker(exp_start, "start")
                elif exp_end is not None and exp_end < t1:
                    cut = int(np.searchsorted(ev["t"][lo:hi], exp_end)) + lo
                    if cut > lo:
                        yield EventBatch(ev[lo:cut])
                    lo = cut
                    yield ExposureMarker(exp_end, "end")
                    yield Frame(self._image(exp_start, exp_end), exp_start, exp_end, self.gain, seq)
                    seq += 1
                    exp_end = None
                else:
                    break
            if hi > lo:
                yield EventBatch(ev[lo:hi])
            i = hi
        del i


def run_once(events, duration_s, fps, batch_us, sink_dir: Path | None, seed: int, sink_cls=None) -> dict:
    """One closed-loop run over ``events``: with the Rerun sink writing a file in ``sink_dir`` (its live
    defaults), or control only (``sink_dir`` None). ``sink_cls``: a :class:`~necviz.dashboard.sink.RerunSink`
    subclass in its place (``benchmarks/sink_cost.py`` takes the sink apart with them)."""
    from necviz.pipeline import Lane, Pipeline

    src = SyntheticStream(events, duration_s, fps, batch_us)
    limits = CameraLimits(10.0, src.period_us - 1_000, 8.0)
    ctrl = make_controller(
        "nec", sensor=DAVIS346, limits=limits, exposure_us=src.exposure_us, event_rate_max=DAVIS_EVENT_RATE_MAX
    )
    observers = []
    rrd = None
    if sink_dir is not None:
        import rerun as rr

        from necviz.dashboard.sink import RerunSink
        from necviz.layouts import make_blueprint, style_series

        rrd = sink_dir / f"bench-{time.perf_counter_ns()}.rrd"
        rec = rr.RecordingStream("necviz-bench", recording_id=f"bench-{seed}")
        rec.set_sinks(
            rr.FileSink(str(rrd)), default_blueprint=make_blueprint("live", ["camera"], DAVIS346.width, DAVIS346.height)
        )
        style_series(rec, ["camera"])
        sink = (sink_cls or RerunSink)(rec, ["camera"], DAVIS346.height, DAVIS346.width)  # live defaults: decimated
        sink.on_close = lambda: rr.disconnect(rec)
        observers.append(sink)
    pipe = Pipeline(src, [Lane("camera", ctrl)], observers=observers)
    t0 = time.perf_counter()
    pipe.run()
    stats = pipe.finish()
    wall = time.perf_counter() - t0  # includes draining the sink's queue and flushing the file
    lat = stats["lanes"]["camera"]
    out = {
        "wall_s": wall,
        "realtime_factor": duration_s / wall,
        "commands": lat["commands"],
        "frames": stats["frames"],
        "events": stats["events"],
        "latency_p50_us": lat["latency_p50_us"],
        "latency_p99_us": lat["latency_p99_us"],
        "latency_max_us": lat["latency_max_us"],
    }
    if "sink" in stats:
        out["sink"] = stats["sink"]
        out["rrd_bytes"] = rrd.stat().st_size
    return out


def run(
    duration_s: float = 10.0,
    rate_mev_s: float = 12.0,
    fps: float = 50.0,
    batch_us: int = 1_000,
    seed: int = 0,
    repeats: int = 3,
    json_path=None,
    out=...,
) -> dict:
    """Run the benchmark; print a table; optionally write JSON."""
    out = output(out)
    if not (0 < duration_s <= 60):
        raise ParameterError(f"--duration must lie in (0, 60] s, got {duration_s}")
    if not (0 < rate_mev_s <= 50):
        raise ParameterError(f"--rate must lie in (0, 50] Mev/s, got {rate_mev_s}")
    if not (1 <= fps <= 200):
        raise ParameterError(f"--fps must lie in 1..200, got {fps}")
    if not (isinstance(repeats, int) and 1 <= repeats <= 20):
        raise ParameterError(f"--repeats must lie in 1..20, got {repeats}")
    if not (100 <= batch_us <= 20_000):
        raise ParameterError(f"--batch-us must lie in 100..20000, got {batch_us}")
    print(
        f"  generating {duration_s:g} s at {rate_mev_s:g} Mev/s ({duration_s * rate_mev_s:.0f} M events)…",
        file=out,
        flush=True,
    )
    events = make_events(duration_s, rate_mev_s, seed)
    # warm-up (Numba compilation / cache load) on a short slice
    warm = events[: int(0.2 * rate_mev_s * 1e6)]
    run_once(warm, 0.2, fps, batch_us, None, seed)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="necviz-bench-") as tmp:
        for name, sink_dir in (("control_only", None), ("with_logging", Path(tmp))):
            runs = []
            for r in range(repeats):
                print(f"\r  {name.replace('_', ' ')}: run {r + 1}/{repeats}…", end="", file=out, flush=True)
                runs.append(run_once(events, duration_s, fps, batch_us, sink_dir, seed))
            runs.sort(key=lambda x: x["wall_s"])
            rows[name] = {**runs[len(runs) // 2], "wall_s_all": [x["wall_s"] for x in runs]}  # the median run
        print(file=out)
    result = {
        "duration_s": duration_s,
        "rate_mev_s": rate_mev_s,
        "fps": fps,
        "batch_us": batch_us,
        "repeats": repeats,
        "events": int(len(events)),
        "runs": rows,
        "targets": {"realtime_factor_with_logging": 19.0, "latency_p99_us": 1000.0},
        "machine": machine(),
    }
    print(
        f"\n  {'run':14s} {'wall s':>7s} {'RT factor':>9s} {'commands':>8s} {'lat p50 µs':>10s} {'lat p99 µs':>10s}",
        file=out,
    )
    for name, r in rows.items():
        print(
            f"  {name:14s} {r['wall_s']:7.2f} {r['realtime_factor']:9.1f} {r['commands']:8d} "
            f"{r['latency_p50_us']:10.1f} {r['latency_p99_us']:10.1f}",
            file=out,
        )
    sk = rows["with_logging"].get("sink", {})
    if sk:
        print(
            f"  sink: {sk['frames_logged']} frames logged, {sk['frames_dropped']} dropped; {sk['event_images']} "
            f"event images; {sk['events_decimated']:,} of {sk['events_seen']:,} events not drawn; "
            f"{rows['with_logging']['rrd_bytes'] / 1e6:.1f} MB written",
            file=out,
        )
    write_result(result, json_path, out)
    return result
