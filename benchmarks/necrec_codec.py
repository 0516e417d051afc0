#!/usr/bin/env python
"""How small and how fast ``.necrec`` recordings are with each packet compression.

Records ``necviz live --device emulated --duration 2 --record`` (the emulated DAVIS346: ~2.7 Mev/s and
50 frames a second) into a temporary folder, reads the stream back into memory, then writes it again
with :class:`necviz.drivers.recordings.native.Recorder` for every compression (``none``, ``lz4``,
``zstd``) and reads each file back with :func:`necviz.drivers.recordings.open_recording`. Reported per
compression: the file's size (and against ``none``, the layout before compression existed, whose
events are 13 bytes each), the write and read rates in events per second of wall time (write: from the
first packet handed over to the file closed and fsynced; read: every packet decoded), and those rates
against the live stream's own rate (a recorder must keep up with the camera, a replay should not lag
it). Run it under the heavy-job lock: the rates are wall time on a shared machine.

usage: python benchmarks/necrec_codec.py [--json benchmarks/results/necrec_codec.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from necviz.core.events import EventBatch
from necviz.drivers.recordings import open_recording
from necviz.drivers.recordings.native import CODECS, Recorder


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=2.0, help="seconds of emulated live stream (default 2)")
    ap.add_argument("--json", default=None, help="write the result as JSON")
    a = ap.parse_args(argv)
    from necviz.bench.timing import machine

    with tempfile.TemporaryDirectory(prefix="necviz-necrec-") as tmp:
        src = Path(tmp) / "live.necrec"
        subprocess.run(
            [sys.executable, "-m", "necviz", "live", "--device", "emulated", "--duration", str(a.duration)]
            + ["--record", str(src), "--save", str(Path(tmp) / "live.rrd"), "--no-prompt"],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rec = open_recording(src)
        packets = list(rec)
        sensor = rec.sensor
        rec.close()
        events = sum(len(p) for p in packets if isinstance(p, EventBatch))
        t = [p.events["t"] for p in packets if isinstance(p, EventBatch) and len(p)]
        stream_s = (int(t[-1][-1]) - int(t[0][0])) / 1e6
        live_rate = events / stream_s
        rows = []
        for name in CODECS:
            path = Path(tmp) / f"{name}.necrec"
            t0 = time.perf_counter()
            with Recorder(path, sensor=sensor, compression=name) as w:
                for p in packets:
                    w.write(p)
            write_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            n = sum(len(p) for p in open_recording(path) if isinstance(p, EventBatch))
            read_s = time.perf_counter() - t0
            assert n == events
            rows.append(
                {
                    "compression": name,
                    "bytes": path.stat().st_size,
                    "write_mev_s": round(events / write_s / 1e6, 2),
                    "read_mev_s": round(events / read_s / 1e6, 2),
                    "write_x_live": round(events / write_s / live_rate, 2),
                    "read_x_live": round(events / read_s / live_rate, 2),
                }
            )
    none = next(r["bytes"] for r in rows if r["compression"] == "none")
    for r in rows:
        r["of_uncompressed"] = round(r["bytes"] / none, 3)
        print(
            f"  {r['compression']:5s} {r['bytes'] / 1e6:7.1f} MB ({r['of_uncompressed']:.2f} of none); write "
            f"{r['write_mev_s']:.1f} Mev/s ({r['write_x_live']:.1f}x live), read {r['read_mev_s']:.1f} Mev/s "
            f"({r['read_x_live']:.1f}x live)"
        )
    result = {
        "benchmark": "necrec_codec",
        "command": "python benchmarks/necrec_codec.py" + (f" --duration {a.duration:g}" if a.duration != 2 else ""),
        "stream": {"seconds": round(stream_s, 3), "events": events, "live_mev_s": round(live_rate / 1e6, 2)},
        "rows": rows,
        "machine": machine(),
    }
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1) + "\n")
        print(f"  wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
