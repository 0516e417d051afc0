"""``necviz sweep show OUT --run HASH``: re-run one run of a sweep in the Rerun dashboard.

The row's exact spec (its ``spec_json`` column) is rebuilt into the same scene, rig, controller,
profile and simulator overrides as :func:`necviz.runs.run_spec` builds, and run through the
dashboard (:func:`necviz.dashboard.session.run`, the ``compare`` layout): a native
viewer, ``--serve``, ``--connect`` or ``--save FILE.rrd``, as ``necviz demo``. The simulator is
deterministic for its seed, so the re-run shows exactly the run in the table; its metrics are
recomputed from the session's telemetry (as :func:`necviz.runs.run_once` computes them) and
checked against the row's.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from necviz.core.errors import ParameterError
from necviz.sweeps.store import Store


def _metrics(lane, scene) -> dict:
    """The run's metrics from a lane's telemetry (the same call as :func:`necviz.runs.run_once`)."""
    from necviz.core.metrics import summarise

    table = lane.table
    m = summarise(
        table.column("exposure_start_us"),
        table.column("over_exposed_rate"),
        table.column("under_exposed_rate"),
        [c.t_us for c in scene.changes],
        None,
        end_us=scene.duration_us,
    )
    return m.as_dict()


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    a, b = float(a), float(b)
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b or (math.isnan(a) and math.isnan(b))
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def show(out, run: str, viewer=None, speed="auto", stream=...) -> dict:
    """Re-run run ``run`` (a hash or its first digits) of the sweep in ``out`` in the dashboard.

    Returns ``{"hash", "spec", "metrics", "row", "matches", "rrd"}``.
    """
    from necviz.dashboard import session as dashboard
    from necviz.dashboard.session import Session, lane_labels
    from necviz.dashboard.viewer import resolve
    from necviz.layouts import make_blueprint
    from necviz.options import SceneOptions, ShowOptions, ViewerOptions, check_param_lanes
    from necviz.outputs import check_run_files
    from necviz.runs import build_rig

    stream = sys.stdout if stream is ... else stream
    store = Store(out)
    store.manifest()
    h = store.find(run)
    row = store.read_row(h)
    spec = json.loads(row["spec_json"])
    show_opts = ShowOptions(speed)  # checked before anything opens
    viewer = resolve(viewer or ViewerOptions(), "sweep-show")  # the headless default filled in
    check_run_files({}, viewer, (), False)  # its --save file, before anything opens
    scen = spec.get("scenario", "tunnel_exit")
    if (scen.endswith(".toml") or "/" in scen) and not Path(scen).is_file():
        raise ParameterError(f"run {h} used the scenario file {scen}, which no longer exists")
    profile = spec.get("profile")
    if isinstance(profile, dict):
        from necviz.core.camera_profile import CameraProfile

        profile = CameraProfile.from_dict(profile, f"run {h}")
    elif profile is not None:
        from necviz.profiles import load_profile

        profile = load_profile(profile)
    sc = SceneOptions(
        scen, seed=spec.get("seed"), duration_s=spec.get("duration_s"), params=dict(spec.get("scenario_params") or {})
    )
    names = list(spec["controllers"])
    check_param_lanes(spec.get("controller_params"), names)
    scene, rig, lanes, limits = build_rig(sc.build(), names, profile, spec.get("controller_params"), spec.get("sim"))
    props = {
        "command": "sweep show",
        "run": h,
        "scenario": sc.name,
        "seed": sc.resolved_seed,
        "duration_s": scene.duration_us / 1e6,
        "scenario_params": sc.params,
        "controllers": ",".join(names),
        "controller_params": spec.get("controller_params"),
        "sim": spec.get("sim"),
        "camera_limits": limits,
        "camera_profile": str(spec.get("profile") or "default DAVIS346 response"),
        "sweep": str(store.root),
    }
    if stream is not None:
        print(
            f"  sweep show {h}: {sc.name} seed {sc.resolved_seed}, {', '.join(names)} "
            f"({props['duration_s']:g} s simulated)",
            file=stream,
        )
    layout = viewer.layout or "compare"
    settings = Session(
        command="sweep show",
        layout=layout,
        title=f"necviz sweep show {h}",
        properties=props,
        show=show_opts,
        lossless=True,
        expected_duration_s=props["duration_s"],
    )
    blueprint = make_blueprint(layout, names, rig.sensor.width, rig.sensor.height, lane_labels(lanes))
    stats = dashboard.run(rig, lanes, viewer, blueprint, settings, stream)
    metrics = _metrics(stats["telemetry"][names[0]], scene)
    checked = {
        k: (v, row.get(k)) for k, v in metrics.items() if k in row and (v is None or isinstance(v, (int, float)))
    }
    matches = row.get("status") == "ok" and all(_same(a, b) for a, b in checked.values())
    if stream is not None:
        if row.get("status") != "ok":
            print(f"  the sweep recorded this run as failed: {row.get('error')}", file=stream)
        elif matches:
            print(
                "  the re-run reproduces the sweep's row: "
                + ", ".join(f"{k} {_txt(a)}" for k, (a, _) in checked.items()),
                file=stream,
            )
        else:
            diff = [f"{k} {_txt(b)} -> {_txt(a)}" for k, (a, b) in checked.items() if not _same(a, b)]
            print(
                f"  warning: the re-run differs from the sweep's row ({'; '.join(diff)}): the code, a file "
                "it reads or the machine changed since the sweep",
                file=stream,
            )
    return {"hash": h, "spec": spec, "metrics": metrics, "row": row, "matches": matches, "rrd": stats.get("rrd")}


def _txt(v) -> str:
    if v is None:
        return "none"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


__all__ = ["show"]
