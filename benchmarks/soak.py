#!/usr/bin/env python
"""Soak: does a long live session's memory grow? ``necviz live --device emulated`` for an hour of
sensor time (faster than real time), its resident memory sampled as it runs.

The session runs as a user would start it (a subprocess, the DAVIS driver on the emulated camera,
NEC closing the loop, the Rerun sink writing a file, telemetry keeping its last frames), on a
scene with lighting steps so the controller keeps commanding. The process's RSS (with its
children) is sampled every ``--every`` seconds against the sensor time the session reports; after
a warm-up (the first ``--warmup`` fraction of the run: Numba compilation, Rerun's buffers, the
telemetry ring filling) and before the last 1 % (the session starts to shut down and free its
buffers), the growth is the least-squares slope of RSS against sensor time, in MB per hour.
Target: < 50 MB per hour.

``--viewer`` connects a viewer for the whole run: a headless Rerun viewer (``rerun --headless``, the
native viewer without a window, rendering on Mesa's software Vulkan driver), started apart from the
session (its own memory is not the session's), with ``--connect`` added to the session's flags; a
watched session paces itself at real time, so an hour of sensor time takes an hour. Either way the
session also writes ``--save``: the script checks that one ``.rrd`` file (and nothing else) is left.

usage: python benchmarks/soak.py [--hours 1.0] [--scenario static_lab] [--viewer]
                                 [--json benchmarks/results/soak.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

PROGRESS = re.compile(r"live:\s+([\d.]+)(?:/[\d.]+)? s sensor time")


def rss_mb(proc: psutil.Process) -> float:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except psutil.NoSuchProcess:
            pass
    return total / 1e6


def start_viewer(memory_limit: str = "1GB") -> tuple[subprocess.Popen, str]:
    """A headless Rerun viewer listening on a free local port; returns it and the URL to connect to."""
    from necviz.dashboard.viewer import _rerun_binary

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, WGPU_BACKEND="vulkan")  # lavapipe: the OpenGL path has no display to use
    viewer = subprocess.Popen(
        [*_rerun_binary(), "--headless", "--port", str(port), "--memory-limit", memory_limit],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return viewer, f"rerun+http://127.0.0.1:{port}/proxy"
        except OSError:
            if viewer.poll() is not None:
                raise SystemExit("the headless viewer did not start") from None
            time.sleep(0.2)
    viewer.kill()
    raise SystemExit("the headless viewer did not listen within 30 s")


def soak(hours: float, scenario: str, every_s: float, warmup: float, out, viewer_url: str | None = None) -> dict:
    duration_s = hours * 3600
    with tempfile.TemporaryDirectory(prefix="necviz-soak-") as tmp:
        rrd = Path(tmp) / "soak.rrd"
        cmd = [
            sys.executable,
            "-m",
            "necviz",
            "live",
            "--device",
            "emulated",
            "--scenario",
            scenario,
            "--duration",
            str(duration_s),
            "--save",
            str(rrd),
            "--no-prompt",
        ] + (["--connect", viewer_url] if viewer_url else [])
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
        ps = psutil.Process(proc.pid)
        sensor_s = [0.0]
        lines: list[str] = []

        def read():
            for line in proc.stdout:
                lines.append(line)
                m = PROGRESS.search(line)
                if m:
                    sensor_s[0] = float(m.group(1))

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        samples = []  # (wall s, sensor s, RSS MB)
        t0 = time.perf_counter()
        t_end = None  # wall time when the sensor time reached its end (then the files are completed)
        while proc.poll() is None:
            time.sleep(every_s)
            try:
                rss = rss_mb(ps)
            except psutil.NoSuchProcess:
                break
            if rss <= 0 or proc.poll() is not None:  # exited (a zombie has no memory to read)
                break
            samples.append((time.perf_counter() - t0, sensor_s[0], rss))
            if t_end is None and sensor_s[0] >= 0.999 * duration_s:
                t_end = time.perf_counter() - t0
            w, s, m = samples[-1]
            print(
                f"\r  {w:7.0f} s wall · {s:8.1f}/{duration_s:.0f} s sensor · RSS {m:7.1f} MB",
                end="",
                file=out,
                flush=True,
            )
        proc.wait()  # the loop may leave before the exit is reaped (a zombie reads as 0 MB)
        t_exit = time.perf_counter() - t0
        reader.join(5)
        print(file=out)
        rrd_mb = rrd.stat().st_size / 1e6 if rrd.exists() else None
        left = sorted(p.name for p in Path(tmp).iterdir())
    if proc.returncode != 0:
        raise SystemExit(f"necviz live failed ({proc.returncode}):\n{''.join(lines[-20:])}")
    arr = np.asarray(samples, float)
    # after warm-up, and before the last 1 %: as the sensor time runs out the session flushes and
    # frees its buffers, which would pull the slope down
    keep = arr[(arr[:, 1] >= warmup * duration_s) & (arr[:, 1] < 0.99 * duration_s)]
    slope = float(np.polyfit(keep[:, 1] / 3600, keep[:, 2], 1)[0]) if len(keep) >= 3 else float("nan")
    wall = float(arr[-1, 0]) if len(arr) else float("nan")
    return {
        "scenario": scenario,
        "sensor_hours": hours,
        "wall_s": wall,
        "speed_x_real_time": duration_s / wall,
        "samples": len(arr),
        "warmup_fraction": warmup,
        "rss_start_mb": float(keep[0, 2]) if len(keep) else None,
        "rss_end_mb": float(keep[-1, 2]) if len(keep) else None,
        "rss_max_mb": float(arr[:, 2].max()),
        "growth_mb_per_hour": slope,
        "target_mb_per_hour": 50.0,
        "rrd_mb": rrd_mb,
        "files_left": left,
        "close_s": None if t_end is None else round(t_exit - t_end, 1),
        "viewer": viewer_url is not None,
        "trace": [[round(w, 1), round(s, 2), round(m, 1)] for w, s, m in samples],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="sensor time in hours (default 1)")
    ap.add_argument("--scenario", default="static_lab", help="the emulated camera's scene (default static_lab)")
    ap.add_argument("--every", type=float, default=5.0, help="seconds between RSS samples (default 5)")
    ap.add_argument("--warmup", type=float, default=0.1, help="fraction of the run left out of the fit (default 0.1)")
    ap.add_argument("--viewer", action="store_true", help="connect a headless Rerun viewer for the whole run")
    ap.add_argument("--json", default=None, help="write the result as JSON")
    args = ap.parse_args()
    from necviz.bench.timing import machine

    viewer, url = start_viewer() if args.viewer else (None, None)
    try:
        res = soak(args.hours, args.scenario, args.every, args.warmup, sys.stderr, url)
    finally:
        if viewer is not None:
            viewer.terminate()
            viewer.wait(30)
    res["command"] = "python benchmarks/soak.py " + " ".join(sys.argv[1:])
    res["machine"] = machine()
    print(
        f"{res['sensor_hours']:g} h of sensor time in {res['wall_s']:.0f} s wall ({res['speed_x_real_time']:.1f}x "
        f"real time); RSS {res['rss_start_mb']:.0f} -> {res['rss_end_mb']:.0f} MB after warm-up (max "
        f"{res['rss_max_mb']:.0f}); growth {res['growth_mb_per_hour']:.1f} MB per hour (target < 50); "
        f"left {res['files_left']} ({res['rrd_mb']:.0f} MB; completed in {res['close_s']} s after the run)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
