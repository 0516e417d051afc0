"""``necviz bench pipeline`` at an earlier commit and at this checkout, in the same run.

A real-time factor measured a month ago on a shared machine is no yardstick today: the machine's
speed drifts by a third from day to day. This script answers "how much of the gap is the code?" the
only fair way, as a ratio measured in one run: it extracts the earlier commit (``git archive``, the
repository is not touched), stages it as an importable ``necviz`` package in a temporary folder, and
runs that commit's ``necviz bench pipeline`` and this checkout's in alternation, each in its own
process, ``--rounds`` times. Each bench call is the command's own (median of ``--repeats`` runs of
10 s of a 12 Mev/s stream, control only and with logging); the table reports the median over
rounds of each side and the ratio now / then.

    python benchmarks/pipeline_then_now.py --then d508595 --json benchmarks/results/pipeline_then_now.json

``d508595`` (2026-11-22) is the commit whose ``benchmarks/results/pipeline.json`` measured 19.7x
real time with logging, the figure the live-camera issue asks to get back to.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from necviz.bench.timing import machine, write_result  # noqa: E402

#: Runs one side's bench in a fresh process and prints its real-time factors as JSON (the module moved
#: from necviz.bench.pipeline to necviz.dashboard.pipeline_speed since the earlier commit).
SNIPPET = """
import json
try:
    from necviz.dashboard import pipeline_speed as bench
except ImportError:
    from necviz.bench import pipeline as bench
r = bench.run(repeats={repeats}, out=None)
print(json.dumps({{k: v["realtime_factor"] for k, v in r["runs"].items()}}))
"""

#: Top-level folders that install as subpackages of ``necviz`` (pyproject.toml's package-dir).
SUBPACKAGES = ("core", "drivers", "layouts")


def stage(commit: str, folder: Path) -> Path:
    """The tree of ``commit`` in ``folder``/src and an importable ``necviz`` package of it in
    ``folder``/pkg (symbolic links, as an editable install maps the folders). Returns the pkg folder."""
    try:
        data = subprocess.run(
            ["git", "-C", str(ROOT), "archive", "--format=tar", commit], capture_output=True, check=True
        ).stdout
    except subprocess.CalledProcessError as e:
        raise SystemExit(f"pipeline_then_now: cannot read commit {commit!r}: {e.stderr.decode().strip()}") from None
    src, pkg = folder / "src", folder / "pkg" / "necviz"
    src.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:  # git's own archive; the "data" filter where it exists
        tar.extractall(src, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    if not (src / "necviz").is_dir():
        raise SystemExit(f"pipeline_then_now: commit {commit!r} has no necviz/ package to run")
    pkg.mkdir(parents=True)
    for entry in (src / "necviz").iterdir():
        (pkg / entry.name).symlink_to(entry)
    for name in SUBPACKAGES:
        if (src / name).is_dir():
            (pkg / name).symlink_to(src / name)
    return pkg.parent


def bench(pythonpath: str | None, repeats: int) -> dict:
    """One ``necviz bench pipeline`` (median of ``repeats`` runs) in a fresh process: its real-time factors."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = pythonpath
    else:
        env.pop("PYTHONPATH", None)
    cwd = tempfile.gettempdir()  # not the checkout: its folders must not shadow the staged package
    out = subprocess.run(
        [sys.executable, "-c", SNIPPET.format(repeats=repeats)], capture_output=True, text=True, env=env, cwd=cwd
    )
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["no message"])[-1]
        raise SystemExit(f"pipeline_then_now: the bench failed ({last})")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--then", default="d508595", help="the earlier commit (default: d508595, 2026-11-22)")
    ap.add_argument("--rounds", type=int, default=3, help="alternations of the two sides (default 3)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per bench call, as the command's --repeats")
    ap.add_argument("--json", help="write the result here")
    args = ap.parse_args(argv)
    if not 1 <= args.rounds <= 20 or not 1 <= args.repeats <= 20:
        raise SystemExit("pipeline_then_now: --rounds and --repeats must lie in 1..20")
    rows: dict[str, list[dict]] = {"then": [], "now": []}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="necviz-then-") as tmp:
        then_path = str(stage(args.then, Path(tmp)))
        sides = [("then", then_path), ("now", None)]
        for k in range(args.rounds):
            for name, path in sides if k % 2 == 0 else sides[::-1]:  # alternate which side goes first
                print(
                    f"\r  round {k + 1}/{args.rounds}: {name}… ({time.perf_counter() - t0:.0f} s)",
                    end="",
                    flush=True,
                )
                rows[name].append(bench(path, args.repeats))
    print()
    med = {
        side: {key: statistics.median(r[key] for r in runs) for key in ("control_only", "with_logging")}
        for side, runs in rows.items()
    }
    ratio = {key: med["now"][key] / med["then"][key] for key in ("control_only", "with_logging")}
    print(f"\n  {'':14s} {'then ' + args.then:>16s} {'now':>8s} {'now / then':>11s}")
    for key in ("control_only", "with_logging"):
        print(f"  {key:14s} {med['then'][key]:15.1f}x {med['now'][key]:7.1f}x {ratio[key]:11.2f}")
    result = {
        "command": "python benchmarks/pipeline_then_now.py --then "
        + f"{args.then} --rounds {args.rounds} --repeats {args.repeats}"
        + (f" --json {args.json}" if args.json else ""),
        "then": args.then,
        "now": subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        ).stdout.strip(),
        "rounds": args.rounds,
        "repeats": args.repeats,
        "realtime_factor": {side: rows[side] for side in rows},
        "median": med,
        "ratio_now_then": ratio,
        "machine": machine(),
    }
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
