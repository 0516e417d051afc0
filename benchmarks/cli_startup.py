#!/usr/bin/env python
"""How fast the command line answers: ``necviz --version``, ``necviz --help`` and a mistyped flag.

Each is run ``--repeats`` times in a fresh process (wall time, from spawning the interpreter to its exit),
through the installed ``necviz`` script and ``python -m necviz``. A bare ``python -c pass`` is timed beside
them: the interpreter's own start, which no package can go below. Figures: median, smallest and largest,
and the load average. (What they must not import is asserted by ``tests/test_cli.py``, not timed there.)

usage: python benchmarks/cli_startup.py [--repeats 7] [--json benchmarks/results/cli_startup.json]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from necviz.bench.timing import machine, spread, write_result  # noqa: E402


def timed(cmd) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, capture_output=True, timeout=120)
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    script = shutil.which("necviz") or str(Path(sys.executable).with_name("necviz"))
    cases = {
        "python -c pass (the interpreter alone)": [sys.executable, "-c", "pass"],
        "necviz --version": [script, "--version"],
        "necviz --help": [script, "--help"],
        "necviz demo --bogus (an argument error)": [script, "demo", "--bogus"],
        "python -m necviz --version": [sys.executable, "-m", "necviz", "--version"],
    }
    result = {"target_s": 0.3, "cases": {}}
    for label, cmd in cases.items():
        timed(cmd)  # the first run fills the OS file cache
        s = spread(timed(cmd) for _ in range(args.repeats))
        result["cases"][label] = s
        print(f"{label:42s} {s['median']:6.3f} s ({s['min']:.3f}..{s['max']:.3f})")
    result["machine"] = machine()
    print(f"load average {result['machine']['load_average']}")
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
