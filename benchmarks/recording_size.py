#!/usr/bin/env python
"""How big the Rerun recordings are, what they hold, and what the encoding costs (issue 15).

Runs ``necviz demo --duration 2 --save DIR/demo.rrd`` (tunnel_exit, six controllers) and
``necviz compare --duration 2 --no-sift --save DIR/compare.rrd`` into a temporary directory, then
reads each file back (``rerun.chunk.RrdReader``) and reports:

* total bytes, and bytes per entity group: ``frames`` (``NAME/frame``), ``event_images``
  (``events``), ``scalars`` (every Scalars entity), ``other`` (styles, text logs, properties) and
  ``rest`` (the blueprint and the file's framing: total minus the groups). A group's bytes are
  those of its chunks written alone with ``LazyChunkStream.write_rrd`` (LZ4, as the SDK writes
  them), minus the bytes of an empty file;
* the sink's encode time (every call of :func:`necviz.dashboard.sink.encode_frame` and
  :meth:`necviz.dashboard.sink.EventPalette.png` during the demo, wall time on the sink's thread);
* frame fidelity: the SSIM (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03;
  mean over the image) of every frame decoded from the file against the frame the simulator
  produced; event images: how many decode to exactly the rendered colours;
* the alternatives, on the demo's own frames and event images: JPEG with the standard table at
  several qualities (OpenCV/libjpeg, optimised Huffman) against :data:`necviz.dashboard.sink.FRAME_QTABLE`,
  and event images as JPEG (quality 85, the previous encoding) against paletted PNG.

Sizes are deterministic (the sink chunks by size, not wall time); times are not (shared machine).

usage: python benchmarks/recording_size.py [--json FILE] [--baseline OLD.rrd]
       (``--baseline``: also break down an older recording of the same command, e.g. one written
       before this change, for the before/after table)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

import necviz.dashboard.sink as sink_mod
from necviz.commands.cli import main
from necviz.core.event_image import EventImage
from necviz.image_quality import ssim

GROUPS = ("frames", "event_images", "scalars", "other", "rest")
DEMO = ["demo", "--duration", "2", "--no-prompt"]
COMPARE = ["compare", "--duration", "2", "--no-sift"]


def _group(entity: str, kinds: set) -> str:
    if "EncodedImage" in kinds:
        if entity == "events":
            return "event_images"
        return "frames" if entity.endswith("/frame") else "other"
    return "scalars" if kinds == {"Scalars"} else "other"


def breakdown(path) -> dict:
    """Total bytes of the file and bytes / chunks / rows per entity group (see the module doc)."""
    from rerun.chunk import LazyChunkStream, RrdReader

    chunks = defaultdict(list)
    for ch in RrdReader(str(path)).stream().to_chunks():
        names = ch.to_record_batch().schema.names
        chunks[_group(str(ch.entity_path).lstrip("/"), {n.split(":", 1)[0] for n in names if ":" in n})].append(ch)
    total = os.path.getsize(path)
    out = {"total": total, "groups": {}}
    with tempfile.TemporaryDirectory() as d:
        f = os.path.join(d, "g.rrd")
        LazyChunkStream.from_iter([]).write_rrd(f, application_id="size", recording_id="size")
        empty = os.path.getsize(f)
        for g in GROUPS[:-1]:
            chs = chunks.get(g, [])
            LazyChunkStream.from_iter(chs).write_rrd(f, application_id="size", recording_id="size")
            out["groups"][g] = {
                "bytes": os.path.getsize(f) - empty if chs else 0,
                "chunks": len(chs),
                "rows": int(sum(c.num_rows for c in chs)),
            }
    out["groups"]["rest"] = {"bytes": total - sum(v["bytes"] for v in out["groups"].values()), "chunks": 0, "rows": 0}
    return out


def logged_images(path, entity: str) -> list[tuple[int, bytes]]:
    """``(t in ns, blob)`` of every EncodedImage row of ``entity``, in time order."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    rows = []
    for ch in RrdReader(str(path)).stream().to_chunks():
        if str(ch.entity_path).lstrip("/") != entity:
            continue
        rb = ch.to_record_batch()
        if "EncodedImage:blob" not in rb.schema.names:
            continue
        t = rb.column("t").cast(pa.int64()).to_pylist()
        for ti, blob in zip(t, rb.column("EncodedImage:blob").to_pylist(), strict=True):
            b = blob[0] if isinstance(blob, list) and blob and isinstance(blob[0], (list, bytes)) else blob
            rows.append((ti, bytes(bytearray(b))))
    return sorted(rows, key=lambda r: r[0])


class Capture:
    """Wraps the sink's encoders during a run: what they were given, what they produced, how long."""

    def __init__(self):
        self.frames, self.frame_bytes, self.frame_s, self.by_blob = [], 0, 0.0, {}
        self.events, self.event_bytes, self.event_s = [], 0, 0.0
        self._f, self._e = sink_mod.encode_frame, sink_mod.EventPalette.png

    def __enter__(self):
        def frame(image, *a, **k):
            t = time.perf_counter()
            out = self._f(image, *a, **k)
            self.frame_s += time.perf_counter() - t
            self.frames.append(image.copy())
            self.by_blob[out] = self.frames[-1]
            self.frame_bytes += len(out)
            return out

        def events(palette, image, *a, **k):
            t = time.perf_counter()
            out = self._e(palette, image, *a, **k)
            self.event_s += time.perf_counter() - t
            self.events.append(image.render())
            self.event_bytes += len(out)
            return out

        sink_mod.encode_frame, sink_mod.EventPalette.png = frame, events
        return self

    def __exit__(self, *exc):
        sink_mod.encode_frame, sink_mod.EventPalette.png = self._f, self._e


def _run(argv: list[str]) -> float:
    t = time.perf_counter()
    if main(argv) != 0:
        raise SystemExit(f"necviz {' '.join(argv)} failed")
    return time.perf_counter() - t


def alternatives(frames: list, event_rgb: list) -> dict:
    """Bytes, SSIM and encode time of the frame and event-image encodings on the demo's own images."""

    def timed(fn, xs):
        t = time.perf_counter()
        out = [fn(x) for x in xs]
        return out, (time.perf_counter() - t) / max(1, len(xs)) * 1e3

    res = {"frames": {}, "event_images": {}}
    cands = {
        f"standard q{q}": (
            lambda f, q=q: cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, q, cv2.IMWRITE_JPEG_OPTIMIZE, 1])[
                1
            ].tobytes()
        )
        for q in (75, 80, 85, 90)
    }
    cands["FRAME_QTABLE (necviz)"] = sink_mod.encode_frame
    for name, enc in cands.items():
        blobs, ms = timed(enc, frames)
        s = np.array(
            [
                ssim(f, cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_GRAYSCALE))
                for f, b in zip(frames, blobs, strict=True)
            ]
        )
        res["frames"][name] = {
            "kb_per_frame": float(np.mean([len(b) for b in blobs]) / 1e3),
            "ssim_mean": float(s.mean()),
            "ssim_p5": float(np.percentile(s, 5)),
            "ssim_min": float(s.min()),
            "ms_per_frame": ms,
        }
    img = EventImage(*event_rgb[0].shape[:2])
    pal = sink_mod.EventPalette(img)
    lut = {tuple(c): i for i, c in enumerate(pal.palette.tolist())}
    indices = []
    for rgb in event_rgb:  # back to indices through the (exact, 5-colour) palette
        idx = np.zeros(rgb.shape[:2], np.uint8)
        for c, i in lut.items():
            idx[(rgb == np.array(c, np.uint8)).all(-1)] = i
        indices.append(idx)
    ev = {
        "jpeg q85 (previous)": lambda i: cv2.imencode(
            ".jpg", np.ascontiguousarray(pal.palette[i][..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 85]
        )[1].tobytes()
    }
    for lvl in (1, 6, 9):
        ev[f"paletted PNG zlib {lvl}"] = lambda i, lvl=lvl: sink_mod.encode_indexed_png(i, pal.palette, lvl)
    for name, enc in ev.items():
        blobs, ms = timed(enc, indices)
        exact = sum(
            bool(
                (
                    cv2.cvtColor(cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
                    == pal.palette[i]
                ).all()
            )
            for b, i in zip(blobs, indices, strict=True)
        )
        res["event_images"][name] = {
            "kb_per_image": float(np.mean([len(b) for b in blobs]) / 1e3),
            "exact": f"{exact}/{len(blobs)}",
            "ms_per_image": ms,
        }
    return res


def fidelity(path, capture: Capture, lanes: list[str]) -> dict:
    """SSIM of every frame in the file against the simulator's frame; exactness of every event image."""
    import io

    from PIL import Image

    logged = [b for lane in lanes for _, b in logged_images(path, f"{lane}/frame")]
    src = capture.by_blob  # each logged blob back to the frame it was encoded from
    s = np.array(
        [ssim(src[b], cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_GRAYSCALE)) for b in logged if b in src]
    )
    ev = logged_images(path, "events")
    exact = sum(
        bool((np.asarray(Image.open(io.BytesIO(b)).convert("RGB")) == rgb).all())
        for (_, b), rgb in zip(ev, capture.events, strict=True)
    )
    return {
        "frames_logged": len(logged),
        "frames_matched": int(len(s)),
        "ssim_mean": float(s.mean()),
        "ssim_p5": float(np.percentile(s, 5)),
        "ssim_min": float(s.min()),
        "event_images_logged": len(ev),
        "event_images_exact": int(exact),
    }


def _table(rows: dict) -> None:
    print(f"  {'recording':22s} {'total':>11s}" + "".join(f" {g:>13s}" for g in GROUPS))
    for name, b in rows.items():
        print(f"  {name:22s} {b['total']:>11,d}" + "".join(f" {b['groups'][g]['bytes']:>13,d}" for g in GROUPS))


def main_(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "recording_size.json"))
    ap.add_argument(
        "--baseline",
        action="append",
        default=[],
        metavar="OLD.rrd",
        help="also break down an older recording (repeatable)",
    )
    args = ap.parse_args(argv)
    lanes = ["nec", "navid", "shim", "begin", "builtin", "fixed"]
    with tempfile.TemporaryDirectory() as d:
        demo, comp = Path(d) / "demo.rrd", Path(d) / "compare.rrd"
        with Capture() as cap:
            wall_demo = _run([*DEMO, "--save", str(demo)])
        wall_compare = _run([*COMPARE, "--save", str(comp)])
        sizes = {"demo": breakdown(demo), "compare": breakdown(comp)}
        fid = fidelity(demo, cap, lanes)
    for p in args.baseline:
        sizes[f"baseline {Path(p).name}"] = breakdown(p)
    print("\nRecording size (bytes):")
    _table(sizes)
    print(
        "\n  chunks / rows per group (demo): "
        + ", ".join(f"{g} {v['chunks']}/{v['rows']}" for g, v in sizes["demo"]["groups"].items() if g != "rest")
    )
    n_f, n_e = len(cap.frames), len(cap.events)
    enc = {
        "frames": n_f,
        "frame_encode_s": cap.frame_s,
        "frame_ms": cap.frame_s / max(1, n_f) * 1e3,
        "frame_kb": cap.frame_bytes / max(1, n_f) / 1e3,
        "event_images": n_e,
        "event_encode_s": cap.event_s,
        "event_ms": cap.event_s / max(1, n_e) * 1e3,
        "event_kb": cap.event_bytes / max(1, n_e) / 1e3,
        "demo_wall_s": wall_demo,
        "compare_wall_s": wall_compare,
    }
    print(
        f"\nEncode time in the demo (sink thread): frames {n_f} x {enc['frame_ms']:.2f} ms = {cap.frame_s:.2f} s "
        f"({enc['frame_kb']:.1f} KB each); event images {n_e} x {enc['event_ms']:.2f} ms = {cap.event_s:.2f} s "
        f"({enc['event_kb']:.1f} KB each); demo wall {wall_demo:.1f} s, compare wall {wall_compare:.1f} s"
    )
    print(
        f"Fidelity (demo file vs the simulator): {fid['frames_matched']}/{fid['frames_logged']} frames, SSIM mean "
        f"{fid['ssim_mean']:.4f}, p5 {fid['ssim_p5']:.4f}, min {fid['ssim_min']:.4f}; event images exact "
        f"{fid['event_images_exact']}/{fid['event_images_logged']}"
    )
    alt = alternatives(cap.frames, cap.events)
    print("\nFrame encodings on the demo's frames:")
    print(f"  {'encoding':24s} {'KB/frame':>9s} {'SSIM mean':>10s} {'p5':>7s} {'min':>7s} {'ms':>6s}")
    for name, r in alt["frames"].items():
        print(
            f"  {name:24s} {r['kb_per_frame']:9.2f} {r['ssim_mean']:10.4f} {r['ssim_p5']:7.4f} {r['ssim_min']:7.4f}"
            f" {r['ms_per_frame']:6.2f}"
        )
    print("Event-image encodings on the demo's event images:")
    for name, r in alt["event_images"].items():
        print(f"  {name:24s} {r['kb_per_image']:9.2f} KB  exact {r['exact']:>7s}  {r['ms_per_image']:6.2f} ms")
    result = {
        "command": {
            "demo": "necviz " + " ".join([*DEMO, "--save", "DIR/demo.rrd"]),
            "compare": "necviz " + " ".join([*COMPARE, "--save", "DIR/compare.rrd"]),
        },
        "sizes": sizes,
        "encode": enc,
        "fidelity": fid,
        "alternatives": alt,
        "frame_qtable": sink_mod.FRAME_QTABLE,
        "ssim_floor": sink_mod.FRAME_SSIM_FLOOR,
    }
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=1))
        print(f"\nwrote {args.json}")
    return result


if __name__ == "__main__":
    sys.exit(0 if main_() else 1)
