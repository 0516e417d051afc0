#!/usr/bin/env python
"""What the fiducial-marker metric costs, and how often it finds the markers (issue 20, item 5).

For every preset (its default duration, seed 0) one closed-loop run of NEC and a fixed exposure
with ``markers=True`` (:func:`necviz.runs.run_once`) collects every frame; then, on those frames:

* the detector's time per frame (:meth:`necviz.marker_detection.MarkerDetector.detect`, CPU time
  of the process, median and 95th percentile over the frames of both lanes) and per scoring call;
* the run's marker figures (detection rate, latency, missed pairs, corner error) per controller;

and, as a same-run ratio, the CPU time of the whole run (every thread of the process) with and
without ``markers`` (``--repeats`` runs each, interleaved, median): how much the metric adds to a
comparison. CPU time rather than wall time, because the development machine's 2 cores are shared
with other jobs (wall times there scatter by +-50 %); it still depends on the machine: read the
ratios, not the ms.

usage: python benchmarks/markers.py [--json FILE] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from necviz.drivers.sim.scenes import SCENARIOS
from necviz.marker_detection import MarkerDetector
from necviz.options import SceneOptions
from necviz.runs import RunOptions, run_once

CONTROLLERS = ("nec", "fixed")


class _Frames:
    """An observer keeping every frame (with its truth) of every lane."""

    def __init__(self):
        self.frames = []

    def __call__(self, rig, lanes):
        from necviz.pipeline import Observer

        keep = self.frames

        class Keep(Observer):
            def frame(self, lane, frame, record):
                keep.append(frame)

        return Keep()


def measure(name: str, repeats: int) -> dict:
    sc = SceneOptions(name, seed=0)
    grab = _Frames()
    res = run_once(RunOptions(sc, tuple(CONTROLLERS), sift=False, markers=True), (grab,))
    det = MarkerDetector()
    t_detect, t_score = [], []
    clock = time.process_time
    for f in grab.frames:
        t0 = clock()
        det.detect(f.image)
        t_detect.append(clock() - t0)
        t0 = clock()
        det.score(f.image, f.truth.markers)
        t_score.append(clock() - t0)
    walls = {"off": [], "on": []}
    for _ in range(repeats):
        for key in ("off", "on"):
            t0 = clock()
            run_once(RunOptions(sc, tuple(CONTROLLERS), sift=False, markers=key == "on"))
            walls[key].append(clock() - t0)
    off, on = float(np.median(walls["off"])), float(np.median(walls["on"]))
    figures = {
        n: {
            k: res["results"][n][k]
            for k in ("frames", "marker_detection_rate", "marker_latency_ms", "marker_missed", "marker_pairs")
        }
        | {"marker_corner_error_px": res["results"][n]["marker_corner_error_px"]}
        for n in CONTROLLERS
    }
    return {
        "scenario": name,
        "duration_s": res["duration_s"],
        "frames": len(grab.frames),
        "markers_in_scene": int(grab.frames[0].truth.markers.ids.size) if grab.frames else 0,
        "detect_ms_median": 1e3 * float(np.median(t_detect)),
        "detect_ms_p95": 1e3 * float(np.percentile(t_detect, 95)),
        "score_ms_median": 1e3 * float(np.median(t_score)),
        "run_cpu_s_without_markers": off,
        "run_cpu_s_with_markers": on,
        "run_time_ratio": on / off,
        "controllers": figures,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--repeats", type=int, default=1, help="runs with and without markers per preset (median)")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'scenario':16s} {'frames':>6s} {'detect ms':>10s} {'p95 ms':>7s} {'run +%':>7s}   per controller")
    for name in SCENARIOS:
        r = measure(name, args.repeats)
        rows.append(r)
        per = "; ".join(
            f"{n}: rate {c['marker_detection_rate']:.3f}, latency {c['marker_latency_ms']:.0f} ms, "
            f"missed {c['marker_missed']}/{c['marker_pairs']}"
            if c["marker_detection_rate"] is not None and c["marker_latency_ms"] is not None
            else f"{n}: rate {c['marker_detection_rate']}"
            for n, c in r["controllers"].items()
        )
        print(
            f"{name:16s} {r['frames']:6d} {r['detect_ms_median']:10.2f} {r['detect_ms_p95']:7.2f} "
            f"{100 * (r['run_time_ratio'] - 1):7.1f}   {per}"
        )
    out = {
        "command": "python benchmarks/markers.py" + (f" --repeats {args.repeats}" if args.repeats != 1 else ""),
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "python": platform.python_version(),
        },
        "controllers": list(CONTROLLERS),
        "scenarios": rows,
    }
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=1)
            f.write("\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
