"""Closed-loop simulator runs, described by plain data: what ``compare``, ``demo`` and sweeps run.

A run is a scene (:class:`~necviz.options.SceneOptions`), the controllers that each drive their own
camera of one :class:`~necviz.drivers.sim.rig.SimRig` (shared scene and events), optional
controller parameters, an optional camera profile for the controllers (response, TEDI thresholds
and compensation) and optional simulator overrides (the DVS and APS models — e.g. thresholds that
differ from the controller's profile). :func:`run_once` runs it through the
:class:`~necviz.pipeline.Pipeline` and returns every controller's metrics and per-frame trace.

:func:`run_spec` takes and returns plain dicts (JSON-ready), for processes that receive a run by
value (Dask workers)::

    {"scenario": "tunnel_exit", "seed": 3, "duration_s": 2.0, "scenario_params": {"step_db": 90},
     "controllers": ["nec"], "controller_params": {"nec": {"goal": 110}},
     "profile": None, "sim": {"dvs.c_on": 0.3, "aps.latency_us": 2000}, "sift": False, "markers": True,
     "dvs": [["c_on", "0.15"], ["refractory_us", "400"]]}

``dvs``: DVS bias settings applied at scene start, as ``--dvs KEY=VALUE`` does on ``demo``
(:mod:`necviz.dvs_controls`: the biases written to the simulated camera, every lane's P-TEDI following them).
Absent or empty, the run is exactly what it was without the key.

``sift`` and ``markers`` (fiducial-marker detection, :mod:`necviz.marker_detection`) are per-frame
measurements that cost time; both default to off in a run spec.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

from necviz.core.control import CONTROLLERS, CameraLimits, Controller, make_controller
from necviz.core.errors import ParameterError
from necviz.core.markers import MARKER_KEYS, summarise_markers
from necviz.core.metrics import summarise, summarise_details
from necviz.options import SceneOptions, check_param_lanes
from necviz.pipeline import Lane, Pipeline
from necviz.telemetry import Telemetry

if TYPE_CHECKING:
    from necviz.drivers.sim.scene import Scene


def sim_models(sim: dict | None):
    """``{"dvs.KEY": v, "aps.KEY": v}`` -> ``(DvsParams, ApsParams)`` with those fields replaced."""
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.dvs import DvsParams

    dvs, aps = DvsParams(), ApsParams()
    for key, value in (sim or {}).items():
        model, _, field = str(key).partition(".")
        models: dict[str, DvsParams | ApsParams] = {"dvs": dvs, "aps": aps}
        target = models.get(model)
        if target is None or field not in {f.name for f in fields(target)}:
            known = [f"dvs.{f.name}" for f in fields(dvs)] + [f"aps.{f.name}" for f in fields(aps)]
            raise ParameterError(f"unknown simulator parameter {key!r}; known: {', '.join(known)}")
        if model == "dvs":
            dvs = replace(dvs, **{field: value})
        else:
            aps = replace(aps, **{field: value})
    return dvs, aps


def build_controller(
    name: str,
    params: dict | None,
    *,
    sensor,
    limits: CameraLimits,
    exposure_us: float,
    profile=None,
    event_rate_max: float | None = None,
) -> Controller:
    """Controller ``name`` (a registered kind, or ``KIND@LABEL`` for a labelled variant) with ``params``:
    fields of its options go to its constructor; any other tunable parameter (the fixed exposure, say)
    is set after building (:meth:`~necviz.core.control.Controller.set_param`). ``event_rate_max`` is
    the source's event bus ceiling (its ``camera_info``), which NEC's escape rule reads."""
    from dataclasses import fields

    from necviz.options import controller_kind

    kind = controller_kind(name)
    kw = {} if profile is None else {"tedi": profile.tedi, "crf": profile.crf}
    params = dict(params or {})
    entry = CONTROLLERS.get(kind)
    option_fields = {f.name for f in fields(entry.cls.OPTIONS)} if entry and entry.cls.OPTIONS else set()
    later = {k: params.pop(k) for k in list(params) if k not in option_fields}
    ctrl = make_controller(
        kind, sensor=sensor, limits=limits, exposure_us=exposure_us, event_rate_max=event_rate_max, **kw, **params
    )
    for k, v in later.items():
        ctrl.set_param(k, v)
    ctrl.name = name
    return ctrl


def build_rig(
    scene: Scene,
    controllers,
    profile=None,
    controller_params: dict | None = None,
    sim: dict | None = None,
    cache=None,
    threads: bool | None = None,
):
    """The rig (one camera per controller) on ``scene`` (:meth:`SceneOptions.build`), and one driving lane
    per controller; returns ``(scene, rig, lanes, limits)``. ``controller_params``: checked by the caller
    (:func:`~necviz.options.check_param_lanes`).

    ``cache``: a :class:`~necviz.drivers.sim.scene_cache.SceneCache` the rig reads the rendered scene from,
    or writes it to (a replayed demo; the packets are the same either way). ``threads``: the rig's
    :attr:`~necviz.drivers.sim.rig.RigOptions.threads` (``False``: all on the caller's thread, as a sweep
    worker runs; the same packets either way)."""
    from necviz.core.ptedi import PeripheralEstimator
    from necviz.core.ptedi_shared import share_event_side
    from necviz.drivers.sim.rig import RigOptions, SimRig

    dvs, aps = sim_models(sim)
    rig = SimRig(
        scene,
        list(controllers),
        dvs=dvs,
        aps=aps,
        seed=scene.seed,
        options=RigOptions(threads=threads),
        cache=cache,
    )
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    profile = profile if profile is not None else simulator_profile()
    lanes = []
    for n in controllers:
        ctrl = build_controller(
            n,
            (controller_params or {}).get(n),
            sensor=scene.sensor,
            limits=limits,
            exposure_us=rig.cams[n].exposure_us,
            profile=profile,
            event_rate_max=rig.camera_info.event_rate_max,  # the simulator's configured ceiling (dvs.max_event_rate)
        )
        passive = None if ctrl.estimator is not None else PeripheralEstimator(scene.sensor, profile.tedi, profile.crf)
        lanes.append(Lane(n, ctrl, estimator=passive))
    # the lanes see the same events with the same thresholds: one compensated event side for all of them
    # (exactly the estimates of separate ones, at a fraction of the work; necviz.core.ptedi_shared)
    share_event_side([ln.estimator for ln in lanes])
    return scene, rig, lanes, limits


def simulator_profile():
    """The camera profile the controllers use in the simulator by default: the one calibrated on the
    simulated DAVIS346 (held-out calibration scene; :func:`necviz.profiles.default_sim_profile`)."""
    from necviz.profiles import default_sim_profile

    return default_sim_profile()


@dataclass(frozen=True)
class RunOptions:
    """One closed-loop run, as plain data.

    Parameters
    ----------
    scene : SceneOptions
        The scene (preset or file, seed, duration, parameters).
    controllers : tuple of str
        Registered controller names (or ``KIND@LABEL`` variants), one camera each.
    sift : bool
        Count SIFT inliers between consecutive frames (slow).
    markers : bool
        Detect the scene's fiducial markers on every frame (the ``marker_*`` figures of
        :func:`necviz.core.markers.summarise_markers`; ``None`` without).
    profile : CameraProfile, optional
        The controllers' camera profile (default: the shipped simulator profile).
    controller_params : dict, optional
        ``{controller: {parameter: value}}``.
    sim : dict, optional
        Simulator overrides ``{"dvs.KEY" | "aps.KEY": value}``.
    threads : bool, optional
        The simulator's worker threads (:class:`~necviz.drivers.sim.rig.RigOptions`; ``False`` on a sweep
        worker, one run per core; the same result either way).
    dvs : tuple of (str, str)
        DVS controls ``(KEY, VALUE)`` applied before the first packet, as ``--dvs KEY=VALUE``
        (:meth:`~necviz.dvs_controls.DvsControls.set`; P-TEDI follows). Empty: the default biases.
    """

    scene: SceneOptions
    controllers: tuple
    sift: bool = True
    markers: bool = False
    profile: object = None
    controller_params: dict | None = None
    sim: dict | None = None
    threads: bool | None = None
    dvs: tuple = ()


def run_once(options: RunOptions, observers=(), progress=None) -> dict:
    """One closed-loop run; returns ``{"results": {name: metrics and traces}, "duration_s", "steps_us"}``.

    ``observers`` are :class:`~necviz.pipeline.Observer` s or factories ``f(rig, lanes)``;
    ``progress(pipe, label, expected_s)`` runs the pipeline (default: on this thread, silently).
    """
    scene_options, controllers, sift, markers = options.scene, options.controllers, options.sift, options.markers
    check_param_lanes(options.controller_params, controllers)
    scene, rig, lanes, _ = build_rig(
        scene_options.build(),
        controllers,
        options.profile,
        options.controller_params,
        options.sim,
        threads=options.threads,
    )
    tel = Telemetry([ln.name for ln in lanes], sift=sift, markers=markers)
    obs = [o(rig, lanes) if callable(o) else o for o in observers]
    pipe = Pipeline(rig, lanes, telemetry=tel, observers=obs)
    for key, value in options.dvs:  # at scene start: the stream begins at these biases, P-TEDI at their thresholds
        pipe.dvs.set(key, value, None, started=False)
    if progress is None:
        pipe.run().finish()
    else:
        progress(pipe, f"{scene_options.name} seed {scene_options.resolved_seed}", scene.duration_us / 1e6)
    steps = [c.t_us for c in scene.changes]
    res = {}
    for n in controllers:
        table = tel[n].table
        starts = table.column("exposure_start_us")
        sift_vals = table.column("sift_inliers") if sift else None
        m = summarise(
            starts,
            table.column("over_exposed_rate"),
            table.column("under_exposed_rate"),
            steps,
            None if sift_vals is None else [None if not math.isfinite(v) else v for v in sift_vals],
            end_us=scene.duration_us,
        )
        details = summarise_details(
            table.column("sequence"),
            table.column("sift_inliers_normalised"),
            table.column("true_valid_fraction"),
            table.column("rank_correlation"),
            table.column("pedestrian_valid_fraction"),
            table.column("saturation_cause"),
        )
        marks = dict.fromkeys(MARKER_KEYS)
        if markers:
            marks = summarise_markers(
                starts,
                table.column("marker_visible_mask"),
                table.column("marker_detected_mask"),
                table.column("marker_corner_error_px"),
                steps,
                scene.duration_us,
            )
        res[n] = {
            **m.as_dict(),
            **details,
            **marks,
            "exposure_trace_us": table.column("exposure_us").tolist(),
            "gain_trace": table.column("gain").tolist(),
            "frame_starts_us": starts.tolist(),
            "frames_detail": table.rows(),
        }
    return {"results": res, "duration_s": scene.duration_us / 1e6, "steps_us": steps}


SPEC_KEYS = {
    "scenario",
    "seed",
    "duration_s",
    "scenario_params",
    "controllers",
    "controller_params",
    "profile",
    "sim",
    "sift",
    "markers",
    "dvs",
}


def run_spec(spec: dict, threads: bool | None = None) -> dict:
    """:func:`run_once` from a plain dict (keys in the module docstring); returns plain data.

    ``threads``: the simulator's worker threads (:attr:`RunOptions.threads`), not part of the spec: the
    result is the same either way."""
    unknown = set(spec) - SPEC_KEYS
    if unknown:
        raise ParameterError(f"unknown run key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(SPEC_KEYS))}")
    scene = SceneOptions(
        spec.get("scenario", "tunnel_exit"),
        seed=spec.get("seed"),
        duration_s=spec.get("duration_s"),
        params=dict(spec.get("scenario_params") or {}),
    )
    profile = spec.get("profile")
    if isinstance(profile, dict):
        from necviz.core.camera_profile import CameraProfile

        profile = CameraProfile.from_dict(profile, "run spec")
    elif profile is not None:
        from necviz.profiles import load_profile

        profile = load_profile(profile)
    from necviz.dvs_controls import check_assignments
    from necviz.options import parse_controllers

    return run_once(
        RunOptions(
            scene,
            tuple(parse_controllers(spec.get("controllers", ["nec"]))),
            sift=bool(spec.get("sift", False)),
            markers=bool(spec.get("markers", False)),
            profile=profile,
            controller_params=spec.get("controller_params"),
            sim=spec.get("sim"),
            threads=threads,
            dvs=check_assignments(f"{k}={v}" for k, v in spec.get("dvs") or ()),
        )
    )


__all__ = [
    "SPEC_KEYS",
    "RunOptions",
    "build_controller",
    "build_rig",
    "run_once",
    "run_spec",
    "sim_models",
    "simulator_profile",
]
