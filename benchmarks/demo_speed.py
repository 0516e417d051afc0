#!/usr/bin/env python
"""How fast the flagship demo plays: sensor seconds per wall second of ``necviz demo --duration 2 --save X.rrd``.

Runs the command as a user does (a fresh process each time) and reads its summary line (``... over 2.00 s
... in W s wall``: the pipeline's wall time, from the first packet to the last; start-up, imports and the
warm-up before the first packet are not in it, the total process time is reported beside it). Two lane
sets: the default six (``nec,navid,shim,begin,builtin,fixed``) and seven (the six plus ``nec@b``, a second
NEC lane standing in for ``nec-frames``, which another branch adds). Each is run with an empty scene cache
(the first run of a scenario: it renders and writes the cache) and then ``--repeats`` times replayed
(:mod:`necviz.drivers.sim.scene_cache`: the scene and its events read back; what a replayed demo does).
Figures: the median with the slowest and fastest run, and the load average of the machine.

usage: python benchmarks/demo_speed.py [--repeats 3] [--json benchmarks/results/demo_speed.json]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from necviz.bench.timing import machine, spread, write_result  # noqa: E402

LANES = {
    "six (default)": None,
    "seven (+ a second NEC lane for nec-frames)": "nec,navid,shim,begin,builtin,fixed,nec@b",
}
SUMMARY = re.compile(r"over ([\d.]+) s .* in ([\d.]+) s wall")


def one(controllers, cache_dir: str, out_dir: str) -> dict:
    cmd = [sys.executable, "-m", "necviz", "demo", "--duration", "2", "--no-prompt", "--force"]
    cmd += ["--save", os.path.join(out_dir, "demo.rrd")]
    if controllers:
        cmd += ["--controllers", controllers]
    env = {**os.environ, "NECVIZ_CACHE_DIR": cache_dir}
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    total = time.perf_counter() - t
    if done.returncode != 0:
        raise SystemExit(f"demo failed: {done.stderr[-2000:]}")
    m = SUMMARY.search(done.stdout)
    sensor, wall = float(m.group(1)), float(m.group(2))
    return {"sensor_s": sensor, "pipeline_wall_s": wall, "sensor_per_wall": sensor / wall, "process_wall_s": total}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    result = {
        "command": "necviz demo --duration 2 --save X.rrd [--controllers ...] (fresh process per run)",
        "lanes": {},
        "target_sensor_per_wall": 1.0,
    }
    print(f"{'lanes':46s} {'cache':9s} {'sensor s / wall s':>30s} {'process s':>10s}")
    with tempfile.TemporaryDirectory(prefix="necviz-demo-speed-") as tmp:
        for label, controllers in LANES.items():
            cache = os.path.join(tmp, "cache-" + str(len(result["lanes"])))
            cold = one(controllers, cache, tmp)
            warm = [one(controllers, cache, tmp) for _ in range(args.repeats)]
            r = {
                "controllers": controllers or "default",
                "cold_cache": cold,
                "replayed": {
                    "sensor_per_wall": spread(w["sensor_per_wall"] for w in warm),
                    "pipeline_wall_s": spread(w["pipeline_wall_s"] for w in warm),
                    "process_wall_s": spread(w["process_wall_s"] for w in warm),
                },
            }
            result["lanes"][label] = r
            print(f"{label:46s} {'empty':9s} {cold['sensor_per_wall']:30.2f} {cold['process_wall_s']:10.1f}")
            s = r["replayed"]["sensor_per_wall"]
            text = f"{s['median']:.2f} ({s['min']:.2f}..{s['max']:.2f})"
            print(f"{'':46s} {'replayed':9s} {text:>30s} {r['replayed']['process_wall_s']['median']:10.1f}")
    result["machine"] = machine()
    print(f"load average {result['machine']['load_average']}")
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
