#!/usr/bin/env python
"""Start the side-by-side demo from Python — no command line to fake — and read its results.

``necviz.run_demo`` takes the same options the ``necviz demo`` command maps its flags onto: the
scene (a preset or a TOML file, its seed, duration and parameter overrides), the controllers, and
where the Rerun data goes (``ViewerOptions(save=...)`` writes a file; ``spawn=True`` opens a native
viewer). It returns the run's summary; its ``telemetry`` holds every frame's metrics per lane.

usage: python examples/demo_from_python.py [--scenario indoor_outdoor] [--duration-s 1.0] [--out demo.rrd]
"""

import argparse

import necviz
from necviz.core.errors import NecvizError
from necviz.flags import in_flag_terms


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="indoor_outdoor", help="a preset name or a TOML scenario file")
    ap.add_argument("--duration-s", type=float, default=1.0, help="simulated seconds")
    ap.add_argument("--out", default="demo.rrd", help="the recording to write (open it with: rerun FILE)")
    args = ap.parse_args()
    try:
        stats = necviz.run_demo(
            necviz.DemoOptions(
                necviz.SceneOptions(args.scenario, seed=0, duration_s=args.duration_s, params={}),
                controllers=("nec", "navid", "fixed"),
            ),
            necviz.ViewerOptions(save=args.out, force=True),
            out=None,
        )
    except NecvizError as e:  # bad options: one line naming the flag, like the command
        raise SystemExit(f"error: {in_flag_terms(e)}") from None
    print(f"{args.scenario}: {stats['duration_s']:.2f} s simulated, {stats['events']:,} events")
    for lane, s in stats["lanes"].items():
        sat = stats["telemetry"][lane].table.column("over_exposed_rate") > 0.5
        print(
            f"  {lane:6s} {s['frames']} frames, {s['saturated_frames_50']} saturated "
            f"(first over-exposed at frame {int(sat.argmax()) if sat.any() else '—'}), {s['commands']} commands"
        )
    print(f"wrote {stats['rrd']} (open it with: rerun {stats['rrd']})")


if __name__ == "__main__":
    main()
