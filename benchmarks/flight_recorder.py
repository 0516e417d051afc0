"""The flight recorder's memory at the DAVIS346's full event rate (12 Mev/s): bounded by its budget.

A stream like ``necviz bench pipeline``'s (346x260 events at 12 Mev/s in 1 ms batches, 50 fps frames,
a command and a prediction per frame), generated on the fly so the generator holds nothing, is fed
straight to a :class:`~necviz.dashboard.flight_recorder.FlightRecorder` (the observer calls the pipeline makes),
as fast as the machine goes. Each scenario runs in its own process; its resident memory (VmRSS) is
sampled every 0.5 s of sensor time and its peak (``ru_maxrss``) read at the end, against the same
process before the recorder existed (the baseline: what a session has loaded and compiled anyway, the
Rerun SDK and the sink's Numba kernels among them), so the peak includes the clip writer's working memory.
The bound to meet: the peak stays within ``--clip-memory`` + 10 %:

* ``quiet``: no failure for 20 s, ``--clip-before 5`` (5 s at 12 Mev/s is 780 MB of events): the ring
  fills to its budget, then drops the oldest (counted) and memory stays flat;
* ``failures``: a saturated frame every 4 s: clips of 5 s before + 2 s after are written (.necrec + .rrd);
* ``saturated``: every frame saturated: the clip being collected is cut at half the data budget, clips
  wait for the writer (at most MAX_PENDING), the rest are dropped (counted).

Run: ``python benchmarks/flight_recorder.py --json benchmarks/results/flight_recorder.json``
(≈ 5 min on 2 cores; clips go to a temporary folder that is removed).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

RATE = 12e6
W, H = 346, 260
SCENARIOS = {
    # name: (seconds, budget MB, failure period s or 0 (none) or -1 (every frame), before, after)
    "quiet": (20.0, 512, 0.0, 5.0, 5.0),
    "quiet-128MB": (20.0, 128, 0.0, 5.0, 5.0),
    "failures": (20.0, 128, 4.0, 5.0, 2.0),
    "saturated": (12.0, 64, -1.0, 5.0, 2.0),
}


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _warm_sink() -> None:
    """What a session has done before its recorder exists: the Rerun sink's kernels compiled (Numba) and
    its encoders loaded (a session's own sink warms them up before the run): the clip writer uses them
    too, and their code (~100 MB of compiler memory the first time) is not the recorder's."""
    import rerun as rr

    from necviz.dashboard.sink import RerunSink, SinkOptions, encode_frame

    rec = rr.RecordingStream("warm-up")  # no sink: nothing is written
    sink = RerunSink(rec, ["camera"], H, W, SinkOptions(lossless=True))
    sink.warm_up()
    encode_frame(np.zeros((H, W), np.uint8))
    sink.close()
    rr.disconnect(rec)


def child(name: str, folder: str) -> dict:
    import rerun  # noqa: F401 - loaded by every session before the recorder exists

    import necviz.dashboard.sink  # noqa: F401
    import necviz.drivers.recordings.native  # noqa: F401
    import necviz.layouts  # noqa: F401
    from necviz.core.control import ExposureCommand
    from necviz.core.events import EVENT_DTYPE
    from necviz.core.frames import ExposureMarker, Frame
    from necviz.core.sensor import DAVIS346
    from necviz.dashboard.flight_recorder import FlightRecorder
    from necviz.memory import bound_heap_retention
    from necviz.options import ClipOptions
    from necviz.telemetry import FrameRecord

    bound_heap_retention()  # as run_session does
    _warm_sink()
    seconds, budget_mb, period, before, after = SCENARIOS[name]
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (H, W), dtype=np.uint8)
    per_batch = int(RATE / 1000)
    base = rss_mb()
    fr = FlightRecorder(
        ClipOptions(folder, before_s=before, after_s=after, memory_mb=budget_mb),
        sensor=DAVIS346,
        lanes={"camera": "camera"},
        drivers={"camera": "camera"},
        layout="live",
    )
    fr.started(0, {})
    samples = []
    wall0 = time.perf_counter()
    seq = 0
    for k in range(int(seconds * 1000)):
        t = k * 1000
        if t % 20_000 == 0:
            fr.packet("camera", ExposureMarker(t, "start"))
        ev = np.empty(per_batch, EVENT_DTYPE)  # a fresh batch, as a camera delivers it
        ev["t"] = t + (np.arange(per_batch) * 1000) // per_batch
        ev["x"] = rng.integers(0, W, per_batch)
        ev["y"] = rng.integers(0, H, per_batch)
        ev["p"] = 1
        fr.events(ev)
        if t % 20_000 == 4_000:
            s, e = t - 4_000, t + 1_000
            fr.packet("camera", ExposureMarker(e, "end"))
            f = Frame(image, s, e, 1.0, seq)
            fr.packet("camera", f)
            sat = period < 0 or (period > 0 and s % int(period * 1e6) == 0 and s > 0)
            fr.frame(
                "camera",
                f,
                FrameRecord(seq, s, e, 5000.0, 1.0, 0.9 if sat else 0.01, 0.0, saturation_cause="controller"),
            )
            fr.command("camera", ExposureCommand(5000.0, 1.0, t), 50.0)
            fr.prediction("camera", t, 1.0)
            seq += 1
        if k % 500 == 0:
            samples.append((t / 1e6, rss_mb() - base))
    feed_s = time.perf_counter() - wall0
    stats = fr.close()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    growth = [g for _, g in samples]
    return {
        "scenario": name,
        "sensor_s": seconds,
        "events": int(seconds * RATE),
        "budget_mb": budget_mb,
        "before_s": before,
        "after_s": after,
        "baseline_rss_mb": round(base, 1),
        "peak_rss_over_baseline_mb": round(peak - base, 1),
        "peak_over_budget": round((peak - base) / budget_mb, 3),
        "within_budget_plus_10pc": bool(peak - base <= 1.1 * budget_mb),
        "rss_over_baseline_last_mb": round(growth[-1], 1),
        "rss_over_baseline_max_sampled_mb": round(max(growth), 1),
        "recorder_peak_mb": round(stats["peak_bytes"] / 2**20, 1),
        "dropped_events": stats["dropped_events"],
        "clips_written": stats["clips_written"],
        "clips_cut": stats["clips_cut"],
        "clips_dropped": stats["clips_dropped"],
        "failures": stats["failures"],
        "feed_wall_s": round(feed_s, 1),
        "rss_samples": [(round(a, 2), round(b, 1)) for a, b in samples[:: max(1, len(samples) // 20)]],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--scenario", choices=list(SCENARIOS), action="append", help="run only these")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--folder", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.folder)))
        return 0
    results = []
    for name in args.scenario or list(SCENARIOS):
        with tempfile.TemporaryDirectory() as folder:
            proc = subprocess.run(
                [sys.executable, __file__, "--child", name, "--folder", folder], capture_output=True, text=True
            )
            if proc.returncode != 0:
                print(proc.stderr, file=sys.stderr)
                return 1
            r = json.loads(proc.stdout.strip().splitlines()[-1])
        results.append(r)
        print(
            f"{name:12s} budget {r['budget_mb']:4d} MB: peak RSS +{r['peak_rss_over_baseline_mb']:7.1f} MB "
            f"({r['peak_over_budget']:.2f} of the budget) "
            f"(recorder's own count {r['recorder_peak_mb']:6.1f} MB), {r['dropped_events']:>12,} events dropped, "
            f"{r['clips_written']} clips written ({r['clips_cut']} cut, {r['clips_dropped']} dropped), "
            f"fed {r['sensor_s']:g} s in {r['feed_wall_s']:g} s",
            flush=True,
        )
    if args.json:
        out = {
            "command": "python benchmarks/flight_recorder.py --json " + args.json,
            "rate_ev_s": RATE,
            "cpu_count": os.cpu_count(),
            "results": results,
        }
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
