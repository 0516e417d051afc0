"""The dashboard screenshots of the docs (``docs/images/dashboard-compare.jpg``, ``dashboard-inspect.jpg``).

Usage (from the repository root; needs Debian's ``chromium``, about three minutes on two cores)::

    python docs/screenshots.py --force            # replace the images in docs/images
    python docs/screenshots.py --out /tmp/shots   # or write them elsewhere

What it runs, so anyone can make the same pictures:

1. ``necviz demo --duration 1.0 --set exit_s=0.8 --save demo.rrd --record demo.necrec`` — the
   ``compare`` layout: the seven default lanes through the simulated tunnel exit (seed 0), the
   portal passed at 0.8 s;
2. ``necviz replay demo.necrec --save replay.rrd`` — the ``inspect`` layout: NEC's camera from the
   same run, replayed in open loop;
3. each ``.rrd`` served with ``rerun --serve-web`` on localhost and shot in headless Chromium at
   1600 x 1000, dark theme (``tests/viewer_check.py``: Chromium driven over the DevTools protocol,
   shots repeated until two in a row are identical).

The web viewer opens a recording at its end, so the run stops 0.2 s after the portal: the time cursor
stands just after the tunnel exit, when NEC has already recovered and the slower controllers have not.
The images are JPEG (quality 88); existing files are kept unless ``--force``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The run shown: the portal at 0.8 s, the recording (and the viewer's cursor) ending 0.2 s later.
DEMO = ["demo", "--duration", "1.0", "--set", "exit_s=0.8", "--no-prompt"]
SHOTS = {"compare": "dashboard-compare.jpg", "inspect": "dashboard-inspect.jpg"}
SIZE = (1600, 1000)


def necviz(args: list[str]) -> None:
    """Run ``necviz ARGS`` with this interpreter; a failure stops the script with its output."""
    cmd = [sys.executable, "-m", "necviz", *args]
    print(f"  $ necviz {' '.join(args)}", flush=True)
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"screenshots: `necviz {' '.join(args)}` failed (exit {out.returncode}):\n{out.stderr or out.stdout}")


def shoot(rrd: Path, target: Path) -> dict:
    """Screenshot ``rrd`` in the web viewer into ``target`` (JPEG); returns the viewer check's evidence."""
    sys.path.insert(0, str(ROOT / "tests"))
    import viewer_check as vc
    from PIL import Image

    png = rrd.with_suffix(".png")
    try:
        ev = vc.browser_screenshot(rrd, png, timeout_s=240, width=SIZE[0], height=SIZE[1], theme="dark")
    except vc.ViewerUnavailable as e:
        sys.exit(f"screenshots: {e}")
    Image.open(png).convert("RGB").save(target, "JPEG", quality=88, optimize=True)
    return ev


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=ROOT / "docs" / "images", help="folder for the images (default docs/images)"
    )
    ap.add_argument("--force", action="store_true", help="replace existing images")
    a = ap.parse_args(argv)
    targets = {layout: a.out / name for layout, name in SHOTS.items()}
    kept = [str(t) for t in targets.values() if t.exists()]
    if kept and not a.force:
        print(f"screenshots: {', '.join(kept)} exist; pass --force to replace them", file=sys.stderr)
        return 2
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="necviz-shots-") as tmp:
        work = Path(tmp)
        print("1/4 the demo (compare layout)", flush=True)
        necviz([*DEMO, "--save", str(work / "demo.rrd"), "--record", str(work / "demo.necrec")])
        print("2/4 its NEC camera replayed (inspect layout)", flush=True)
        necviz(["replay", str(work / "demo.necrec"), "--save", str(work / "replay.rrd")])
        rows = []
        for k, (layout, rrd) in enumerate((("compare", work / "demo.rrd"), ("inspect", work / "replay.rrd")), 3):
            print(f"{k}/4 {layout}: web viewer in headless Chromium (about a minute)", flush=True)
            ev = shoot(rrd, targets[layout])
            rows.append((layout, targets[layout], ev))
    print(f"\n{'layout':<9} {'image':<40} {'KB':>5} {'shots':>5} {'stable':>6} {'s':>5}")
    for layout, path, ev in rows:
        print(
            f"{layout:<9} {str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path):<40} "
            f"{path.stat().st_size // 1024:>5} {ev['screenshots_until_stable']:>5} {str(ev['stable']):>6} "
            f"{ev['elapsed_s']:>5.0f}"
        )
    print(f"done in {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
