"""What work on the *other* core costs ``necviz bench pipeline``'s control loop, in one run.

The bench's loop (12 Mev/s, 1 ms batches, 50 fps, NEC closed loop, no observer) runs pinned to one
CPU, in alternation, ``--rounds`` times each, while the machine's other CPU is

* ``idle``: nothing else runs;
* ``python spin``: a separate process (no GIL shared with the loop) pinned there, counting in a loop;
* ``numpy sum``: a separate process pinned there, summing a 400 MB array over and over (memory-bound);
* ``GIL switches``: a thread of the loop's own process on the other CPU that wakes every 20 ms (as the
  Rerun sink's worker does) and releases the GIL ``--switches`` times (``time.sleep(0)``), each release
  making the loop hand it over and take it back; it does no other work.

The first three tell whether the two CPUs share a physical core (or the hypervisor time-slices them):
a process that shares nothing with the loop should cost it nothing on a machine with two real cores.
The last measures what each GIL handover costs the loop. Both bound what a logging thread (or
process) can cost the control loop on this machine, whatever it does. Linux only (CPU affinity).

    python benchmarks/cpu_contention.py --json benchmarks/results/cpu_contention.json
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from necviz.bench.timing import command_line, machine, median_table, write_result  # noqa: E402
from necviz.dashboard import pipeline_speed as bench  # noqa: E402

SPIN = "import os, sys\nos.sched_setaffinity(0, {int(sys.argv[1])})\nx = 0\nwhile True:\n    x += 1\n"
NUMPY_SUM = (
    "import os, sys\nimport numpy as np\nos.sched_setaffinity(0, {int(sys.argv[1])})\n"
    "a = np.ones(50_000_000)\nwhile True:\n    a.sum()\n"
)


class Switcher:
    """A thread on CPU ``cpu`` that wakes every ``period_s`` and releases the GIL ``n`` times."""

    def __init__(self, n: int, cpu: int, period_s: float = 0.02):
        self.n, self.cpu, self.period_s = n, cpu, period_s
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        os.sched_setaffinity(0, {self.cpu})  # this thread only (Linux): where the sink's worker would run
        while not self.stop.wait(self.period_s):
            for _ in range(self.n):
                time.sleep(0)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=9, help="runs of each condition, alternated (default 9)")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of stream per run (default 10)")
    ap.add_argument("--switches", type=int, default=10, help="GIL releases per 20 ms wake (default 10)")
    ap.add_argument("--json", help="write the result here")
    args = ap.parse_args(argv)
    if not 1 <= args.rounds <= 50 or not 0 < args.duration <= 60 or not 1 <= args.switches <= 1000:
        raise SystemExit("cpu_contention: --rounds must lie in 1..50, --duration in (0, 60], --switches in 1..1000")
    if not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2:
        raise SystemExit("cpu_contention: needs Linux and at least two CPUs to pin the loop and the other work")
    here, other = sorted(os.sched_getaffinity(0))[:2]
    print(f"  generating {args.duration:g} s at 12 Mev/s…", flush=True)
    events = bench.make_events(args.duration, 12.0)
    os.sched_setaffinity(0, {here})  # the loop's process (and the switcher thread) on one CPU
    bench.run_once(events[: len(events) // 50], args.duration / 50, 50.0, 1_000, None, 0)  # kernels loaded
    conditions = ("idle", "python spin", "numpy sum", "GIL switches")
    walls: dict[str, list[float]] = {c: [] for c in conditions}
    t0 = time.perf_counter()
    for k in range(args.rounds):
        for c in conditions:
            print(f"\r  round {k + 1}/{args.rounds}: {c}… ({time.perf_counter() - t0:.0f} s)", end="", flush=True)
            proc = switcher = None
            if c in ("python spin", "numpy sum"):
                code = SPIN if c == "python spin" else NUMPY_SUM
                proc = subprocess.Popen([sys.executable, "-c", code, str(other)])
                time.sleep(1.0 if c == "numpy sum" else 0.3)  # running (the array allocated) before the clock
            elif c == "GIL switches":
                switcher = Switcher(args.switches, other)
            try:
                walls[c].append(bench.run_once(events, args.duration, 50.0, 1_000, None, 0)["wall_s"])
            finally:
                if proc is not None:
                    proc.kill()
                    proc.wait()
                if switcher is not None:
                    switcher.close()
    print()
    med = median_table(walls, args.duration, "other CPU", "idle", ("x idle", lambda w, base: w / base))
    base = med["idle"]
    result = {
        "command": command_line("benchmarks/cpu_contention.py", ap, args),
        "duration_s": args.duration,
        "rounds": args.rounds,
        "switches_per_wake": args.switches,
        "wall_s": walls,
        "median_wall_s": med,
        "slowdown": {c: w / base for c, w in med.items()},
        "machine": machine(),
    }
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
