#!/usr/bin/env python
"""Command latency in the run summary: ``necviz live --device emulated`` and ``necviz replay`` of a short file.

The latency of a command is the processing time from the moment the packet that caused it left the
source (the pipeline received it) to the moment the command was handed back to the source; start-up is
not in it (every kernel is compiled or loaded before the first packet, :mod:`necviz.warmup`). Each command
is run ``--repeats`` times in a fresh process; the summary's p50 and p99 are read from its output.
Figures: the median over runs with the smallest and largest, and the load average.

usage: python benchmarks/latency.py [--repeats 3] [--json benchmarks/results/latency.json]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from necviz.bench.timing import machine, spread, write_result  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346_sample.aedat4"
LINE = re.compile(r"(\d+) commands, processing p50 ([\d.]+) µs p99 ([\d.]+) µs")


def commands(out_dir: str) -> dict:
    out = {
        "live --device emulated": ["live", "--device", "emulated", "--duration", "2", "--no-prompt"],
    }
    if SAMPLE.is_file():
        out[f"replay {SAMPLE.name} (0.17 s)"] = ["replay", str(SAMPLE)]
    return {
        k: [sys.executable, "-m", "necviz", *v, "--save", os.path.join(out_dir, "x.rrd"), "--force"]
        for k, v in out.items()
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    result = {"target_p99_us": 1000.0, "commands": {}}
    print(f"{'command':40s} {'commands':>9s} {'p50 µs':>22s} {'p99 µs':>26s}")
    with tempfile.TemporaryDirectory(prefix="necviz-latency-") as tmp:
        for label, cmd in commands(tmp).items():
            runs = []
            for _ in range(args.repeats):
                done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
                if done.returncode != 0:
                    raise SystemExit(f"{label} failed: {done.stderr[-2000:]}")
                m = LINE.search(done.stdout)
                runs.append((int(m.group(1)), float(m.group(2)), float(m.group(3))))
            p50, p99 = spread(r[1] for r in runs), spread(r[2] for r in runs)
            result["commands"][label] = {
                "command": " ".join(["necviz", *cmd[3:]]),
                "commands_per_run": [r[0] for r in runs],
                "p50_us": p50,
                "p99_us": p99,
            }
            print(
                f"{label:40s} {runs[0][0]:9d} {p50['median']:8.0f} ({p50['min']:.0f}..{p50['max']:.0f}) "
                f"{p99['median']:10.0f} ({p99['min']:.0f}..{p99['max']:.0f})"
            )
    result["machine"] = machine()
    print(f"load average {result['machine']['load_average']}")
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
