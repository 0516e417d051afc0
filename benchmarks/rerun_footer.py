#!/usr/bin/env python
"""Where a long session's memory goes, outside necviz: Rerun's file sink and its footer index.

``benchmarks/soak.py`` measured 30–68 MB per hour of ``necviz live --save``. This script sends a
Rerun ``FileSink`` what necviz's live sink sends per 2 s of sensor time (12 scalar series as
columns, 5 JPEG frames of 346 x 260, the file batcher of ``necviz.dashboard.viewer.file_batching``)
``--speed`` times faster than real time, and fits the resident set against stream time after a
20 % warm-up, for three ways of writing the file, each in its own process:

* ``footer``: ``FileSink(path)``, Rerun's default: the file ends with an index of every chunk;
* ``no-footer``: ``FileSink(path, write_footer=False)``;
* ``rotate``: ``FileSink(path)`` replaced by a new file every ``--rotate-min`` minutes of stream.

usage: python benchmarks/rerun_footer.py [--hours 1] [--speed 20] [--rotate-min 10]
                                         [--json benchmarks/results/rerun_footer.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def child(mode: str, hours: float, speed: float, rotate_min: float, folder: str) -> dict:
    import io
    import os
    import time
    import uuid

    import numpy as np
    import psutil
    import rerun as rr
    from PIL import Image

    from necviz.dashboard.viewer import file_batching

    rec = rr.RecordingStream("footer", recording_id=str(uuid.uuid4()), batcher_config=file_batching())
    part = 0

    def sink():
        return rr.FileSink(os.path.join(folder, f"{mode}-{part}.rrd"), write_footer=mode != "no-footer")

    rec.set_sinks(sink())
    rng = np.random.default_rng(0)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, (260, 346), dtype=np.uint8)).save(buf, "JPEG")
    blob = buf.getvalue()
    proc = psutil.Process()
    series = [f"camera/series/{k}" for k in range(12)]
    t_stream, last_rotation, samples = 0.0, 0.0, []
    while t_stream < hours * 3600:
        t = ((t_stream + np.arange(100) * 0.02) * 1e6).astype(np.int64)
        index = [rr.TimeColumn("t", duration=t.astype("timedelta64[us]"))]
        for e in series:
            rec.send_columns(e, indexes=index, columns=rr.Scalars.columns(scalars=rng.random(100)))
        for k in range(0, 100, 10):
            rec.set_time("t", duration=np.timedelta64(int(t[k]), "us"))
            rec.log("camera/frame", rr.EncodedImage(contents=blob, media_type="image/jpeg"))
        t_stream += 2.0
        time.sleep(2.0 / speed)
        if mode == "rotate" and t_stream - last_rotation >= rotate_min * 60:
            part += 1
            last_rotation = t_stream
            rec.set_sinks(sink())
        samples.append((t_stream, proc.memory_info().rss / 1e6))
    rec.flush()
    rr.disconnect(rec)
    s = np.array(samples)
    fit = s[len(s) // 5 :]
    slope = float(np.polyfit(fit[:, 0] / 3600, fit[:, 1], 1)[0])
    size = sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder) if f.startswith(mode))
    return {
        "mode": mode,
        "stream_hours": t_stream / 3600,
        "rss_start_mb": round(float(fit[0, 1]), 1),
        "rss_end_mb": round(float(fit[-1, 1]), 1),
        "growth_mb_per_hour": round(slope, 1),
        "files": part + 1,
        "bytes": size,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, default=1.0, help="hours of stream time per mode")
    ap.add_argument("--speed", type=float, default=20.0, help="stream time per wall time")
    ap.add_argument("--rotate-min", type=float, default=10.0, help="minutes of stream per file (rotate)")
    ap.add_argument("--json", default=str(HERE / "results" / "rerun_footer.json"))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--folder", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(a.child, a.hours, a.speed, a.rotate_min, a.folder)))
        return 0
    from importlib.metadata import version

    rows = []
    for mode in ("footer", "no-footer", "rotate"):
        with tempfile.TemporaryDirectory(prefix="necviz-footer-") as tmp:
            out = subprocess.run(
                [sys.executable, __file__, "--child", mode, "--folder", tmp, "--hours", str(a.hours)]
                + ["--speed", str(a.speed), "--rotate-min", str(a.rotate_min)],
                capture_output=True,
                text=True,
                check=True,
            )
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
            r = rows[-1]
            print(
                f"  {mode:10s} {r['stream_hours']:.2f} h of stream: {r['rss_start_mb']:.0f} -> {r['rss_end_mb']:.0f} MB, "
                f"{r['growth_mb_per_hour']:+.1f} MB/h ({r['files']} file(s), {r['bytes'] / 1e6:.0f} MB)",
                flush=True,
            )
    result = {
        "benchmark": "rerun_footer",
        "command": f"python benchmarks/rerun_footer.py --hours {a.hours:g} --speed {a.speed:g} --rotate-min {a.rotate_min:g}",
        "rerun_sdk": version("rerun-sdk"),
        "python": platform.python_version(),
        "rows": rows,
    }
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1) + "\n")
        print(f"  wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
