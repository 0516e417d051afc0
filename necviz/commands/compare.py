"""``necviz compare``: every controller in closed loop on the same simulated scene.

All cameras share one scene and one event stream (:class:`~necviz.drivers.sim.rig.SimRig`);
each controller drives its own camera through the same :class:`~necviz.pipeline.Pipeline` as
``necviz demo``, so a comparison and a demo of the same scene produce the same recording
(``--save``: the same entity schema and the ``compare`` layout, written losslessly). NEC sees
events and frames, the image-only baselines see their frames (they receive the event batches
too, and ignore them). Every controller starts from the same exposure (right for the scene's
first instant) under the same camera limits.

With ``seeds > 1`` every metric is reported as the mean over seeds with a 95 % confidence
interval (Student's t on the per-seed values). Seeds are independent replicates: each draws its
lighting-change times at its own phase of the frame clock (the presets' ``change_jitter_ms``,
:mod:`necviz.drivers.sim.scenes`); ``lighting_steps_us_per_seed`` lists them (``lighting_steps_us``:
the first seed's). Each controller's ``saturation_causes`` counts its
saturated frames by diagnosed cause (:mod:`necviz.core.diagnosis`), as the mean per run over seeds;
with one seed every frame's cause is in ``frames_detail``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.commands.args import (
    add_scene_args,
    controller_choices,
    controller_list,
    scene_options,
)
from necviz.progress import output

if TYPE_CHECKING:
    from necviz.options import CompareOptions
    from necviz.pipeline import Pipeline

METRICS = (
    "frames",
    "saturated_frames_50",
    "saturated_frames_10",
    "mean_over_exposed_rate",
    "mean_under_exposed_rate",
    "recovery_ms",
    "sift_inliers_mean",
    "sift_inliers_normalised_mean",
    "true_valid_fraction_mean",
    "rank_correlation_mean",
    "pedestrian_valid_fraction",
    "pedestrian_well_exposed",
    "marker_detection_rate",
    "marker_latency_ms",
    "marker_missed",
    "marker_corner_error_px",
)


def run_pipeline(pipe: Pipeline, label: str, expected_s: float, out) -> dict:
    """Run ``pipe`` on its thread with a live count on ``out``; Ctrl-C stops it (what ran is kept)."""
    from necviz.progress import LiveLine

    line = LiveLine(out)
    pipe.start()
    t0 = time.perf_counter()
    try:
        while not pipe.wait(0.5):
            t = ((pipe.now_us or 0) - (pipe.first_us or 0)) / 1e6
            line.show(f"  {label}: {t:5.2f}/{expected_s:g} s simulated ({time.perf_counter() - t0:4.1f} s)")
    except KeyboardInterrupt:
        pipe.stop()
        pipe.finish()
        raise
    line.clear()
    return pipe.finish()


#: compare's table: (header, metric, digits, what it means); a column no controller has a value for is left out
COLUMNS = (
    ("frames", "frames", 0, "frames each camera recorded"),
    ("sat>50%", "saturated_frames_50", 1, "frames with more than 50 % of their pixels clipped (>= 250 or <= 9 DN)"),
    ("sat>10%", "saturated_frames_10", 1, "frames with more than 10 % of their pixels clipped"),
    ("mean over", "mean_over_exposed_rate", 3, "mean fraction of a frame's pixels at >= 250 DN"),
    ("mean under", "mean_under_exposed_rate", 3, "mean fraction of a frame's pixels at <= 9 DN"),
    (
        "recovery ms",
        "recovery_ms",
        1,
        "mean time from a lighting step until every later frame has under 10 % of its "
        "pixels clipped (—: some step never recovered)",
    ),
    ("SIFT inliers", "sift_inliers_mean", 1, "mean SIFT matches between consecutive frames (--no-sift skips it)"),
    ("SIFT norm.", "sift_inliers_normalised_mean", 1, "the same on brightness-normalised frames"),
    (
        "true valid",
        "true_valid_fraction_mean",
        3,
        "mean fraction of pixels whose true irradiance was recorded within the valid range (simulator truth)",
    ),
    (
        "rank ρ",
        "rank_correlation_mean",
        3,
        "mean Spearman rank correlation of a frame's digits with the true "
        "irradiance on its valid pixels (1: order kept)",
    ),
    (
        "pedestrian",
        "pedestrian_valid_fraction",
        2,
        "valid fraction of the pedestrian's box on the first frame that shows it (tunnel_exit)",
    ),
)


def _num(v):
    """A metric for :func:`_fmt`: counts stay whole, everything else (NumPy scalars too) a float."""
    return v if isinstance(v, int) and not isinstance(v, bool) else float(v)


def _fmt(v, ci=None, digits=1):
    if v is None:
        return "—"
    s = f"{v:.{digits}f}" if isinstance(v, float) else str(v)
    if ci:
        s += f" ± {ci:.{digits}f}"
    return s


def run(options: CompareOptions | None = None, out=...) -> dict:
    """Run every controller in closed loop on one simulated scene, over ``options.seeds`` seeds.

    Parameters
    ----------
    options : CompareOptions, optional
        The scene, the controllers, seeds, metrics, outputs (default: ``CompareOptions()``).
    out : file, optional
        Where progress and the table are printed (default: standard output; ``None``: nothing).

    Returns
    -------
    dict
        Per controller every metric (mean, its 95 % confidence interval and, over several seeds, the
        per-seed values), the diagnosed causes of saturated frames, what the events add
        (``events_add``: ``nec`` − ``nec-frames`` paired by seed) and each seed's lighting-change times.

    Raises
    ------
    ParameterError
        Bad options or output files.
    """
    from necviz.options import CompareOptions
    from necviz.outputs import check_distinct, check_output, check_space, failure_note

    out = output(out)
    options = options or CompareOptions()
    outputs = {"--json": options.json, "--save": options.save}
    sc = options.scene
    inputs = {"profile": options.profile, "scenario": sc.scenario if sc.is_file else None}
    check_distinct(outputs)
    for flag, path in outputs.items():
        if path is not None:
            check_output(
                path, flag, inputs=inputs, force=options.force, suffixes=(".rrd",) if flag == "--save" else None
            )
    if options.save:
        check_space(options.save, "--save")
    profile = _profile(options.profile)
    names = list(options.controllers)
    seed0 = sc.resolved_seed
    sinks: list = []  # the --save file: committed when everything succeeded, deleted otherwise

    def file_sink(rig, lanes):
        sink = _file_sink(options, rig, lanes)
        sinks.append(sink)
        return sink

    try:
        result = _run(options, names, sc, seed0, profile, file_sink, out)
        for sink in sinks:
            sink.output.commit()
    except BaseException as e:
        new = failure_note(e, [sink.output.discard() for sink in sinks])
        if new is e:
            raise
        raise new from None
    if options.save and out is not None:
        print(f"wrote {options.save} (open it with: rerun {options.save})", file=out)
    return result


def _run(options: CompareOptions, names, sc, seed0, profile, file_sink, out) -> dict:
    import numpy as np

    from necviz.core.metrics import confidence_interval
    from necviz.outputs import write_json
    from necviz.runs import RunOptions, run_once

    runs = []
    reactions = []  # per run: each lane's reaction in sensor time (necviz.reaction)

    def run_and_measure(pipe, label, s):
        run_pipeline(pipe, label, s, out)
        reactions.append({n: r.summary() for n, r in pipe.reactions.items()})

    for k in range(options.seeds):
        observers = ()
        if k == 0 and options.save:
            observers = (file_sink,)
        runs.append(
            run_once(
                RunOptions(
                    replace(sc, seed=seed0 + k),
                    tuple(names),
                    sift=options.sift,
                    markers=options.markers,
                    profile=profile,
                    controller_params=options.controller_params,
                    sim=options.sim,
                ),
                observers,
                progress=run_and_measure,
            )
        )
    table = {}
    for n in names:
        row = {}
        for key in METRICS:
            vals = [r["results"][n][key] for r in runs]
            if any(v is None for v in vals):
                row[key] = row[key + "_std"] = row[key + "_ci95"] = None
                row[key + "_missing"] = sum(v is None for v in vals)
            else:
                mean, ci = confidence_interval(vals)
                row[key] = vals[0] if options.seeds == 1 else mean
                row[key + "_std"] = float(np.std(vals, ddof=1)) if options.seeds > 1 else 0.0
                row[key + "_ci95"] = ci
            if options.seeds > 1:
                row[key + "_per_seed"] = vals
        causes = [r["results"][n].get("saturation_causes") or {} for r in runs]
        row["saturation_causes"] = {
            c: sum(k.get(c, 0) for k in causes) / len(runs) for c in dict.fromkeys(c for k in causes for c in k)
        }
        if options.seeds > 1:
            row["saturation_causes_per_seed"] = causes
        row["reaction"] = reactions[0].get(n) if options.seeds == 1 else None
        if options.seeds > 1:
            row["reaction_per_seed"] = [r.get(n) for r in reactions]
        if options.seeds == 1:
            for key in (
                "recovery_ms_per_step",
                "marker_changes",
                "exposure_trace_us",
                "gain_trace",
                "frame_starts_us",
                "frames_detail",
            ):
                row[key] = runs[0]["results"][n][key]
        table[n] = row
    result = {
        "scenario": sc.name,
        "seed": seed0,
        "seeds": options.seeds,
        "duration_s": runs[0]["duration_s"],
        "scenario_params": sc.params,
        "controller_params": options.controller_params,
        "sim": options.sim,
        "markers": options.markers,
        "profile": str(options.profile) if options.profile else None,
        "lighting_steps_us": runs[0]["steps_us"],
        "lighting_steps_us_per_seed": [r["steps_us"] for r in runs],
        "controllers": table,
    }
    events = events_added(runs, names)
    if events is not None:
        result["events_add"] = events
    if out is not None:
        print_table(result, out)
        if events is not None:
            print_events(events, out)
    if options.json:
        write_json(options.json, result, indent=1, flag="--json")
        if out is not None:
            print(f"wrote {options.json}", file=out)
    return result


def print_table(result: dict, out) -> None:
    from necviz.wording import CAUSE_WORDS, reaction_line

    seeds = result["seeds"]
    print(
        f"\n{result['scenario']}, {result['duration_s']:g} s, seed {result['seed']}"
        + (f" (+{seeds - 1} more; mean ± 95 % CI)" if seeds > 1 else ""),
        file=out,
    )
    table = result["controllers"]
    w = max(10, *(len(n) for n in table))  # controller names registered by users may be longer
    shown = [col for col in COLUMNS if any(r.get(col[1]) is not None for r in table.values())]  # no empty column
    cells = {
        n: [
            _fmt(None if r.get(key) is None else _num(r[key]), r.get(key + "_ci95"), digits)
            for _, key, digits, _ in shown
        ]
        for n, r in table.items()
    }
    widths = [max(len(head), *(len(c[i]) for c in cells.values())) for i, (head, *_) in enumerate(shown)]
    print(
        f"{'controller':{w}s}  " + "  ".join(f"{h:>{wd}s}" for (h, *_), wd in zip(shown, widths, strict=True)), file=out
    )
    for n, row in cells.items():
        print(f"{n:{w}s}  " + "  ".join(f"{c:>{wd}s}" for c, wd in zip(row, widths, strict=True)), file=out)
    hidden = [h for h, key, *_ in COLUMNS if (h, key) not in {(c[0], c[1]) for c in shown}]
    print("columns:", file=out)
    for head, _, _, meaning in shown:
        print(f"  {head:<12s} {meaning}", file=out)
    if hidden:
        print(f"  (not measured in this run, left out: {', '.join(hidden)})", file=out)
    if any(r.get("marker_detection_rate") is not None for r in table.values()):
        print(
            "fiducial markers: detection rate (detected / visible, all frames), latency after each lighting change "
            "(ms; a marker never detected counts its whole window), missed (change, marker) pairs, corner error (px):",
            file=out,
        )
        for n, r in table.items():
            c = lambda k, r=r: r.get(k + "_ci95")  # noqa: E731
            print(
                f"  {n:{w}s} rate {_fmt(r.get('marker_detection_rate'), c('marker_detection_rate'), 3)}, "
                f"latency {_fmt(r.get('marker_latency_ms'), c('marker_latency_ms'))} ms, "
                f"missed {_fmt(r.get('marker_missed'), c('marker_missed'), 1 if seeds > 1 else 0)}, "
                f"corner error {_fmt(r.get('marker_corner_error_px'), c('marker_corner_error_px'), 2)} px",
                file=out,
            )
    reacted = {n: r.get("reaction") or ((r.get("reaction_per_seed") or [None])[0]) for n, r in table.items()}
    lines = {n: reaction_line(v) for n, v in reacted.items()}
    if any(lines.values()):
        print("reaction in sensor time" + (" (first seed)" if seeds > 1 else "") + ":", file=out)
        for n, line in lines.items():
            if line:
                print(f"  {n:{w}s} {line.removeprefix('reaction (sensor time): ')}", file=out)
    print("saturated frames by diagnosed cause" + (" (mean per run)" if seeds > 1 else "") + ":", file=out)
    for n, r in table.items():
        causes = r.get("saturation_causes") or {}
        text = (
            "; ".join(
                f"{CAUSE_WORDS.get(k, k.replace('_', ' '))} ({_fmt(float(v), digits=1 if seeds > 1 else 0)})"
                for k, v in sorted(causes.items(), key=lambda kv: -kv[1])
                if v
            )
            or "none"
        )
        print(f"  {n:{w}s} {text}", file=out)


#: the metrics "what the events add" reports (nec minus nec-frames, paired by seed)
EVENT_METRICS = ("saturated_frames_50", "saturated_frames_10", "true_valid_fraction_mean")


def events_added(runs: list[dict], names) -> dict | None:
    """``nec`` − ``nec-frames`` per metric, paired by seed (both saw the same scene and events):
    ``{metric: {"mean", "ci95", "per_seed"}}``; ``None`` unless both lanes ran."""
    from necviz.core.metrics import confidence_interval

    if "nec" not in names or "nec-frames" not in names:
        return None
    out = {}
    for key in EVENT_METRICS:
        d = [r["results"]["nec"][key] - r["results"]["nec-frames"][key] for r in runs]
        if any(v is None for v in d):
            continue
        mean, ci = confidence_interval(d)
        out[key] = {"mean": mean, "ci95": ci, "per_seed": d}
    return out


def print_events(events: dict, out) -> None:
    """One line: what the events add (nec − nec-frames, paired by seed)."""
    parts = []
    for key, label in (("saturated_frames_50", "sat>50%"), ("saturated_frames_10", "sat>10%")):
        e = events.get(key)
        if e is not None:
            parts.append(f"{label} {e['mean']:+.1f}" + (f" ± {e['ci95']:.1f}" if e["ci95"] else ""))
    n = len(next(iter(events.values()))["per_seed"]) if events else 0
    print(
        f"what the events add (nec − nec-frames, paired over {n} seed{'s' if n != 1 else ''}): "
        + (", ".join(parts) or "—"),
        file=out,
    )


def _profile(path):
    if path is None:
        return None
    from necviz.profiles import load_profile

    return load_profile(path)


def _file_sink(options: CompareOptions, rig, lanes):
    """The dashboard's sink, writing losslessly to ``options.save`` with the ``compare`` layout."""
    from necviz.dashboard.sink import open_file_sink

    sc = options.scene
    props = {
        "command": "compare",
        "scenario": sc.name,
        "seed": sc.resolved_seed,
        "scenario_params": sc.params,
        "controllers": ",".join(ln.name for ln in lanes),
        "profile": options.profile or "default",
    }
    return open_file_sink(
        options.save, [ln.name for ln in lanes], rig.sensor, "compare", f"necviz compare: {sc.name}", props
    )


def add_arguments(p) -> None:
    from necviz.flags import number
    from necviz.names import COMPARE_CONTROLLERS

    add_scene_args(p)
    p.add_argument(
        "--controllers",
        type=controller_list,
        default=",".join(COMPARE_CONTROLLERS),
        help=f"comma-separated, from {', '.join(controller_choices())} (default: {', '.join(COMPARE_CONTROLLERS)})",
    )
    p.add_argument("--seeds", type=number("--seeds"), default=1, help="repeat over this many seeds: mean ± 95 %% CI")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--save", metavar="FILE.rrd", help="write a Rerun recording (the demo's schema and layout)")
    p.add_argument("--no-sift", action="store_true", help="skip the SIFT inlier metric (the slowest part)")
    p.add_argument(
        "--markers",
        action="store_true",
        help="detect the scene's fiducial markers on every frame: detection rate, latency after each "
        "lighting change, corner error (about 2 ms a frame)",
    )
    p.add_argument("--profile", metavar="FILE.json", help="camera profile (CRF, TEDI thresholds and compensation)")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME.KEY=VALUE",
        help="a controller parameter (repeatable), e.g. --param nec.goal=110 --param navid.target_msv=3",
    )
    p.add_argument(
        "--sim",
        action="append",
        default=[],
        metavar="MODEL.KEY=VALUE",
        help="a simulator model parameter (repeatable), e.g. --sim dvs.max_event_rate=1e9",
    )
    p.add_argument("--force", action="store_true", help="replace existing output files")


def _command(args) -> int:
    from necviz.options import CompareOptions, parse_params

    sim = {f"{model}.{k}": v for model, kv in parse_params(args.sim, "--sim").items() for k, v in kv.items()}
    run(
        CompareOptions(
            scene_options(args),
            args.controllers,
            seeds=args.seeds,
            sift=not args.no_sift,
            json=args.json,
            save=args.save,
            force=args.force,
            profile=args.profile,
            controller_params=parse_params(args.param),
            sim=sim,
            markers=args.markers,
        )
    )
    return 0


COMMAND = Command(
    name="compare",
    help="NEC versus the baselines in closed loop on one simulated scene",
    description=None,
    add_arguments=add_arguments,
    run=_command,
)
