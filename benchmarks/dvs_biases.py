"""DVS biases on the emulated DAVIS346: events at libcaer's default biases and at lower thresholds (issue 29).

Part A runs ``necviz live --device emulated`` (the whole driver path: bias words written by the 0xC2 request,
the emulated pixel following them, P-TEDI following the model) on ``static_lab``, with the default biases and with
``--dvs c_on=0.15 --dvs c_off=0.15``, and reads from each run its summary (events, P-TEDI's thresholds) and its
``.necrec`` (the bias change recorded). Part B simulates the same scene with the same thresholds and splits the
count: threshold crossings, lost to the refractory period, lost to the 12 Mev/s event bus, noise.
Both are repeated with slow light changes (``ramp_ms``), where neither limit binds. Part C replays each
lower-threshold recording with P-TEDI following the recorded change and without (the profile's thresholds):
P-TEDI's prediction error against the frames (ln), the ablation of "P-TEDI follows".

    python benchmarks/dvs_biases.py --json benchmarks/results/dvs_biases.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOW = (("c_on", "0.15"), ("c_off", "0.15"))
SCENES = (("static_lab", {}), ("static_lab, ramp_ms=300", {"ramp_ms": 300.0}))


def live_run(scene_params: dict, dvs, duration_s: float, folder: Path, tag: str) -> dict:
    rec = folder / f"{tag}.necrec"
    cmd = [sys.executable, "-m", "necviz", "live", "--device", "emulated", "--scenario", "static_lab"]
    cmd += ["--duration", str(duration_s), "--no-prompt", "--record", str(rec), "--save", str(folder / f"{tag}.rrd")]
    for k, v in scene_params.items():
        cmd += ["--set", f"{k}={v}"]
    for k, v in dvs:
        cmd += ["--dvs", f"{k}={v}"]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=True).stdout
    wall = time.perf_counter() - t0
    events = int(re.search(r"^\s+([\d,]+) events,", out, re.M).group(1).replace(",", ""))
    m = re.search(r"P-TEDI c_on ([\d.]+) c_off ([\d.]+)", out)
    from necviz.drivers.recordings.native import NativeRecording

    notes = [d["dvs"] for _, d in NativeRecording(str(rec)).annotations if "dvs" in d]
    return {
        "command": " ".join(["necviz", *cmd[3:]]),
        "replay": replay_errors(rec) if dvs else None,
        "events": events,
        "ptedi": {"c_on": float(m.group(1)), "c_off": float(m.group(2))} if m else None,
        "recorded_changes": [{"key": n["key"], "value": n["value"], "words": n["words"]} for n in notes],
        "wall_s": round(wall, 1),
    }


def replay_errors(rec: Path) -> dict:
    """P-TEDI's prediction error (RMSE, ln, against the frames) replaying ``rec`` with and without following its
    recorded bias changes (NEC in open loop, as ``necviz replay``)."""
    from necviz.core.control import CameraLimits
    from necviz.drivers.recordings import open_recording
    from necviz.pipeline import Lane, Pipeline
    from necviz.runs import make_controller

    out = {}
    for follow in (True, False):
        recording = open_recording(rec)
        lane = Lane("camera", make_controller("nec", sensor=recording.sensor, limits=CameraLimits()), drives=False)
        pipe = Pipeline(recording, [lane], warm_up=False)
        if follow:
            pipe.dvs.follow_recording(recording.annotations)
        s = pipe.run().finish()["lanes"]["camera"]
        key = "following" if follow else "not_following"
        out[key] = {"rmse_ln": s["prediction_error_rmse"], "frames": s["prediction_error_frames"], **s["ptedi"]}
    return out


def sim_breakdown(scene_params: dict, c: float | None, duration_s: float) -> dict:
    """The simulated DAVIS346 (one camera, no exposure loop: events do not depend on it) at thresholds ``c``."""
    import necviz.drivers.sim.rig as R
    from necviz.core.biases import BiasModel, DvsBiases, DvsSettings, DvsState
    from necviz.core.events import EventBatch
    from necviz.drivers.sim.dvs import DvsParams, params_for_biases
    from necviz.drivers.sim.scenes import make_scenario

    made = []

    class Spy(R.EventSimulator):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    base = DvsParams()
    b = DvsBiases.defaults()
    if c is not None:
        st = DvsState(BiasModel("DAVIS346", DvsSettings(base.c_on, base.c_off, base.refractory_us, base.cutoff_hz)))
        for k in ("c_on", "c_off"):
            st.apply(st.request(k, c))
        b = st.biases
    params = params_for_biases(base, b)
    scene = make_scenario("static_lab", duration_us=int(duration_s * 1e6), seed=0, **scene_params)
    orig, R.EventSimulator = R.EventSimulator, Spy
    try:
        rig = R.SimRig(scene, ["camera"], dvs=params, seed=0)
        n = sum(len(p.events) for _, p in rig.packets() if isinstance(p, EventBatch))
    finally:
        R.EventSimulator = orig
    s = made[-1]
    return {
        "c_on": params.c_on,
        "c_off": params.c_off,
        "events": int(n),
        "crossings": s.crossings,
        "lost_refractory": s.dropped_by_refractory,
        "lost_bus_ceiling": s.dropped_by_ceiling,
        "shot_noise": s.shot_noise_events,
        "leak_hz": params.leak_hz,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="seconds of scene (default: static_lab's 5)")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, params in SCENES:
            row = {"scene": name}
            for tag, dvs in (("default", ()), ("low", LOW)):
                print(f"  {name}: live --device emulated, {tag} biases…", file=sys.stderr, flush=True)
                row[f"live_{tag}"] = live_run(params, dvs, args.duration, Path(tmp), f"{len(rows)}{tag}")
                row[f"sim_{tag}"] = sim_breakdown(params, None if tag == "default" else 0.15, args.duration)
            row["events_ratio"] = row["live_low"]["events"] / row["live_default"]["events"]
            row["crossings_ratio"] = row["sim_low"]["crossings"] / row["sim_default"]["crossings"]
            rows.append(row)
    print(
        f"\n{'scene':26s} {'events default':>15s} {'events c=0.15':>14s} {'ratio':>6s} {'crossings ratio':>16s} "
        f"{'lost to bus (def/low)':>22s} {'lost to refractory':>20s}  P-TEDI"
    )
    for r in rows:
        sd, sl = r["sim_default"], r["sim_low"]
        print(
            f"{r['scene']:26s} {r['live_default']['events']:15,d} {r['live_low']['events']:14,d} "
            f"{r['events_ratio']:6.2f} {r['crossings_ratio']:16.2f} "
            f"{sd['lost_bus_ceiling']:>10,d}/{sl['lost_bus_ceiling']:<11,d} "
            f"{sd['lost_refractory']:>9,d}/{sl['lost_refractory']:<10,d} {r['live_low']['ptedi']}"
        )
    if args.json:
        out = {
            "command": "python benchmarks/dvs_biases.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "rows": rows,
            "machine": {"load_average": list(os.getloadavg()), "cpus": os.cpu_count()},
        }
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
