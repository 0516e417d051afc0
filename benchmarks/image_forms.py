#!/usr/bin/env python
"""Which image side of P-TEDI predicts better: the paper's ``g(mean Z)`` (Eq. 15) or the mean over
valid pixels of ``g(Z)`` (consistent with Eq. 8)? The result is discussed in docs/method.md.

Static analytic scenes (tests/analytic.py) with texture contrast ``sigma`` (the spread of
ln L across pixels) are exposed ``offset`` ln units away from the goal (0 = well exposed,
|offset| >= 1 = partly saturated). For each form we report

* ``err``: the anchor ``ln P`` minus the true mean log irradiance (what Eq. 2 needs);
* ``next``: mean ``g(Z)`` of the next frame, taken with the exposure NEC commands from that
  anchor, minus the goal ``g(I_opt)`` (0 = the next frame is centred on the goal);
* ``sat``: the fraction of saturated pixels (<= 9 or >= 250) in that next frame.

usage: python benchmarks/image_forms.py [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from analytic import AnalyticScene, Trajectory, texture  # noqa: E402

from necviz.core.control import CameraLimits, NECController, NECOptions  # noqa: E402
from necviz.core.crf import default_davis346  # noqa: E402
from necviz.core.event_model import TediParams  # noqa: E402
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions  # noqa: E402
from necviz.core.sensor import SensorGeometry  # noqa: E402
from necviz.core.stream import interleave  # noqa: E402


def measure(sigma: float, offset: float, form: str, crf, w=128, h=96) -> dict:
    base = texture(w, h)
    log_tex = base / base.std() * sigma
    scene = AnalyticScene(w, h, [Trajectory("flat")], log_level=6.0, log_texture=log_tex)
    mean_log = scene.mean_log_irradiance(0)
    t_good = math.exp(crf.goal_log_exposure - mean_log) * 1e6
    t0 = max(2, round(t_good * math.exp(offset)))
    frame = scene.frame(crf, 0, t0)
    est = PeripheralEstimator(
        SensorGeometry(w, h), TediParams(), crf, options=PeripheralOptions(image_form=form, min_valid_fraction=0.01)
    )
    for pk in interleave(scene.events(0.26, 0.24), [frame]):
        est.feed(pk)
    lp = est.predict(t0)
    nec = NECController(
        est, CameraLimits(1, 1e6, 1.0), exposure_us=t0, options=NECOptions(dead_band=0.0, full_band=1e-6)
    )
    cmd = nec.command_for(lp, t0)
    t1 = round(cmd.exposure_us) if cmd else t0
    nxt = scene.frame(crf, 100_000, 100_000 + t1).image
    return {
        "err": lp - mean_log,
        "next": float(crf.g[nxt].mean() - crf.goal_log_exposure),
        "sat": float(((nxt <= 9) | (nxt >= 250)).mean()),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the table as JSON")
    args = ap.parse_args(argv)
    crf = default_davis346()
    rows = []
    print(
        f"{'sigma':>5s} {'offset':>6s} | {'paper err':>9s} {'next':>6s} {'sat':>5s} | {'mean_log err':>12s} {'next':>6s} {'sat':>5s}"
    )
    for sigma in (0.25, 0.5, 1.0):
        for offset in (-2.0, -1.0, 0.0, 1.0, 2.0):
            r = {"sigma": sigma, "offset": offset}
            for form in ("paper", "mean_log"):
                r[form] = measure(sigma, offset, form, crf)
            rows.append(r)
            p, m = r["paper"], r["mean_log"]
            print(
                f"{sigma:5.2f} {offset:6.1f} | {p['err']:9.3f} {p['next']:6.3f} {p['sat']:5.2f} | "
                f"{m['err']:12.3f} {m['next']:6.3f} {m['sat']:5.2f}"
            )
    summary = {}
    for form in ("paper", "mean_log"):
        errs = np.array([r[form]["err"] for r in rows])
        nxt = np.array([r[form]["next"] for r in rows])
        summary[form] = {
            "rmse_err": float(np.sqrt(np.mean(errs**2))),
            "rmse_next": float(np.sqrt(np.mean(nxt**2))),
            "mean_sat_next": float(np.mean([r[form]["sat"] for r in rows])),
        }
        print(
            f"{form:8s}: RMSE vs mean ln L {summary[form]['rmse_err']:.3f}, next frame off goal (RMSE) "
            f"{summary[form]['rmse_next']:.3f}, next frame saturated {summary[form]['mean_sat_next']:.3f}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
