#!/usr/bin/env python
"""The live loop's reaction in sensor time at every speed: ``necviz live --device emulated`` (issue 27 item 1).

Runs ``necviz live --device emulated --scenario static_lab --duration 6 --speed S --json ...`` for each
speed (default ``1``, ``4`` and ``max``), each in a fresh process, and reads its ``--json`` summary: saturated
frames, the exposure changes and how many reached a frame, ``frames_late`` (exposures that started between
the packet that caused a change and the first exposure that used it) p50/p99/max, the cause-to-exposure
time p50/p99 in sensor time, the processing latency, the reader's deepest backlog (sensor time), events the
device dropped and how far the emulated sensor's clock slipped behind the wall clock (a simulation slower
than real time on a loaded machine). Target: at ``--speed 1`` within 2 saturated frames of ``--speed max``,
and ``frames_late`` p99 ≤ 1 at every speed.

``--usb single,libusb1,pyusb`` runs each of the driver's readers (``live --usb``) at each speed, interleaved
(repeat, speed, reader), so they are compared under the same load; ``--duration`` shortens the runs.

usage: python benchmarks/live_reaction.py [--speeds 1,4,max] [--repeats 1] [--usb READERS] [--duration 6]
       [--json benchmarks/results/live_reaction.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from necviz.bench.timing import machine, write_result  # noqa: E402

ARGS = ["live", "--device", "emulated", "--scenario", "static_lab", "--no-prompt"]


def run_one(speed: str, tmp: str, usb: str | None = None, duration: str = "6") -> dict:
    js, rrd = os.path.join(tmp, f"live-{speed}.json"), os.path.join(tmp, f"live-{speed}.rrd")
    extra = ["--duration", duration] + ([] if usb is None else ["--usb", usb])
    cmd = [sys.executable, "-m", "necviz", *ARGS, *extra, "--speed", speed, "--json", js, "--save", rrd, "--force"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"--speed {speed} failed: {done.stderr[-2000:]}")
    summary = json.loads(Path(js).read_text(encoding="utf-8"))
    lane = summary["lanes"]["camera"]
    reader = summary.get("reader", {})
    return {
        "command": " ".join(["necviz", *ARGS, *extra, "--speed", speed, "--json", "FILE"]),
        "usb": summary.get("usb"),
        "wall_s": summary["wall_s"],
        "frames": lane["frames"],
        "saturated_frames": lane["saturated_frames"],
        "commands": lane["commands"],
        "exposure_changes": lane["exposure_changes"],
        "changes_applied": lane["changes_applied"],
        "frames_late": lane["frames_late"],
        "command_to_exposure_us": lane["command_to_exposure_us"],
        "processing_latency_p99_us": lane["processing_latency_p99_us"],
        "reader_lag_peak_us": reader.get("lag_peak_us"),
        "dropped_events": reader.get("dropped_events"),
        "events": summary.get("events"),
        "clock_slip_s": summary.get("emulator", {}).get("clock_slip_s"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--speeds", default="1,4,max")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--usb", default=None, help="readers to compare, e.g. single,libusb1,pyusb (default: live's)")
    ap.add_argument("--duration", default="6")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    speeds = [s.strip() for s in args.speeds.split(",") if s.strip()]
    readers: list[str | None] = [u.strip() for u in args.usb.split(",") if u.strip()] if args.usb else [None]
    command = f"python benchmarks/live_reaction.py --speeds {','.join(speeds)} --repeats {args.repeats}"
    if args.usb:
        command += f" --usb {','.join(str(u) for u in readers)}"
    if args.duration != "6":
        command += f" --duration {args.duration}"
    result: dict = {
        "command": command,
        "scenario": "static_lab",
        "duration_s": float(args.duration),
        "target": {"saturated_within_of_max": 2, "frames_late_p99": 1},
        "runs": [],
    }
    head = (
        f"{'speed':>6s} {'usb':>8s} {'wall s':>7s} {'frames':>6s} {'sat>50%':>7s} {'changes':>9s} {'late p50/p99/max':>17s} "
        f"{'cause→exp p50/p99 ms':>21s} {'proc p99 ms':>11s} {'backlog ms':>10s} {'dropped':>8s} {'slip s':>7s}"
    )
    print(head)
    with tempfile.TemporaryDirectory(prefix="necviz-live-reaction-") as tmp:
        for _ in range(args.repeats):
            for speed in speeds:
                for usb in readers:
                    r = run_one(speed, tmp, usb, args.duration)
                    r["speed"] = speed
                    result["runs"].append(r)
                    _print(r, speed)
    result["machine"] = machine()
    print(f"load average {result['machine']['load_average']}")
    write_result(result, args.json, sys.stdout)
    return 0


def _ms(v) -> str:
    return "—" if v is None else f"{v / 1000:.1f}"


def _print(r: dict, speed: str) -> None:
    late, lag = r["frames_late"], r["command_to_exposure_us"]
    usb = (r.get("usb") or {}).get("library", "?")
    print(
        f"{speed:>6s} {usb:>8s} {r['wall_s']:7.1f} {r['frames']:6d} {r['saturated_frames']:7d} "
        f"{r['changes_applied']:>4}/{r['exposure_changes']:<4} "
        f"{late['p50']!s:>5}/{late['p99']!s}/{late['max']!s:<5} "
        f"{_ms(lag['p50']):>10s}/{_ms(lag['p99']):<10s} {_ms(r['processing_latency_p99_us']):>11s} "
        f"{_ms(r['reader_lag_peak_us']):>10s} {r['dropped_events']!s:>8} {r['clock_slip_s']!s:>7}",
        flush=True,
    )


if __name__ == "__main__":
    sys.exit(main())
