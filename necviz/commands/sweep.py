"""``necviz sweep plan|run|status|report|show``: the command line of :mod:`necviz.sweeps`."""

from __future__ import annotations

import json
import sys

from necviz.commands import Command


def _clock(s) -> str:
    from necviz.sweeps.engine import _clock as c

    return c(s)


def _cmd_plan(args) -> int:
    from necviz.sweeps.engine import default_workers
    from necviz.sweeps.planning import calibrate, describe, estimate
    from necviz.sweeps.spec import load_plan

    plan = load_plan(args.file)
    desc = describe(plan)
    workers = args.workers or default_workers()
    est = None if args.no_estimate else estimate(plan, workers, calibrate(plan), desc)
    if est is not None and plan.metrics and est.get("metrics"):
        from necviz.sweeps.spec import SweepFileError

        bad = [m for m in plan.metrics if m not in est["metrics"]]
        if bad:
            raise SweepFileError(
                f"{args.file}: metrics: {', '.join(repr(m) for m in bad)} not among the runs' "
                f"metrics ({', '.join(est['metrics'])})"
            )
    if args.json:
        print(
            json.dumps(
                {**{k: v for k, v in desc.items() if k != "seeds_list"}, "file": args.file, "estimate": est},
                indent=1,
                default=str,
            )
        )
        return 0
    print(f"sweep {args.file}: {desc['name']}")
    print(
        f"  {desc['scenario_configurations']} scenario configurations × {desc['profiles']} profile(s) × "
        f"{desc['controller_configurations']} controller configurations × {desc['seeds']} seeds = "
        f"{desc['runs']:,} runs ({desc['cells']:,} cells)"
        + (f"; {desc['duplicates_dropped']} duplicate runs dropped" if desc["duplicates_dropped"] else "")
    )
    print(f"  controllers: {', '.join(desc['controllers'])}")
    for k, v in desc["swept"].items():
        shown = ", ".join("none" if x is None else str(x) for x in v[:12]) + (" …" if len(v) > 12 else "")
        print(f"  swept {k}: {shown}")
    print(
        f"  seeds: {_seeds(desc['seeds_list'])}; SIFT {'on' if desc['sift'] else 'off'}; "
        f"markers {'on' if desc.get('markers') else 'off'}; "
        f"{desc['simulated_s']:,.1f} s simulated in total"
    )
    if desc["metrics"]:
        print(f"  report metrics: {', '.join(desc['metrics'])}")
    if est is None:
        pass  # --no-estimate
    elif "error" in est:
        print(f"  no estimate: the calibration run failed ({est['error']})")
    else:
        print(
            f"  estimate: {est['per_sim_s']:.2f} s per simulated second (one calibration run here: "
            f"{est['scenario']}/{est['controller']}, {est['duration_s']:g} s simulated in {est['run_s']:.1f} s) → "
            f"{est['run_s_total']:,.0f} s of runs, about {_clock(est['wall_s'])} on {workers} "
            f"worker{'s' if workers != 1 else ''}"
        )
    return 0


def _seeds(seeds) -> str:
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})"
    return ",".join(map(str, seeds))


def _cmd_run(args) -> int:
    from necviz.sweeps.engine import SweepOptions, run_sweep
    from necviz.sweeps.spec import load_plan

    options = SweepOptions(
        workers=args.workers,
        scheduler=args.scheduler,
        resume=args.resume,
        force=args.force,
        retry_failed=args.retry_failed,
        retries=args.retries,
        dashboard=args.dashboard,
    )
    plan = load_plan(args.file)
    res = run_sweep(plan, args.out, options, stream=sys.stderr)
    if args.json:
        print(json.dumps(res.as_dict(), indent=1))
    else:
        print(
            f"sweep: {res.ok} ok, {res.failed} failed this session ({res.skipped} were already done); "
            f"{res.runs} runs in {res.out}"
            + (f"; summarise with: necviz sweep report {res.out}" if res.left == 0 else "")
        )
    return 0


def _cmd_status(args) -> int:
    from necviz.sweeps.engine import status

    st = status(args.out)
    if args.json:
        print(json.dumps(st, indent=1, default=str))
        return 0
    print(f"sweep {st['out']} ({st['name']}, from {st['sweep_file']})")
    print(f"  {st['runs']} runs: {st['ok']} ok, {st['failed']} failed, {st['missing']} missing")
    if st["unreadable_note"]:
        print(f"  warning: {st['unreadable_note']}")
    if st["run_s_mean"] is not None:
        print(f"  run time: {st['run_s_total']:,.1f} s in total, {st['run_s_mean']:.2f} s per run")
    for err, n in st["errors"].items():
        print(f"  failed with {err}: {n}")
    for f in st["failed_runs"][:5]:
        print(f"    {f['hash']}: {f['error']}")
    last = st["last_session"]
    if last:
        print(
            f"  last session: {last.get('started')} → {last.get('finished', '?')}"
            + (" (interrupted)" if last.get("interrupted") else "")
        )
    if st["missing"]:
        print(f"  `necviz sweep run {st['sweep_file']} --out {st['out']} --resume` runs the missing ones")
    return 0


def _cmd_report(args) -> int:
    from necviz.sweeps.report import report

    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    plot_metrics = [m.strip() for m in args.plot.split(",") if m.strip()] if args.plot else None
    report(
        args.out,
        metrics=metrics,
        folder=args.report_dir,
        force=args.force,
        plot_metrics=plot_metrics,
        stream=sys.stdout,
    )
    return 0


def _cmd_show(args) -> int:
    from necviz.commands.sweep_show import show
    from necviz.dashboard.viewer_flags import viewer_options

    show(args.out, args.run, viewer_options(args), speed=args.speed)
    return 0


def add_arguments(p) -> None:
    from necviz.flags import number

    sub = p.add_subparsers(dest="sweep_command", metavar="SUBCOMMAND", required=True)

    pl = sub.add_parser("plan", help="the expanded grid's size and an estimated time (from a short calibration run)")
    pl.add_argument("file", metavar="FILE.toml", help="the sweep file")
    pl.add_argument(
        "--workers",
        type=number("--workers"),
        default=None,
        metavar="N",
        help="workers the estimate assumes (default: the cores here)",
    )
    pl.add_argument("--no-estimate", action="store_true", help="skip the calibration run")
    pl.add_argument("--json", action="store_true", help="print machine-readable counts (JSON) instead")
    pl.set_defaults(sweep_run=_cmd_plan)

    run = sub.add_parser("run", help="run the grid; finished runs are kept, --resume completes an interrupted sweep")
    run.add_argument("file", metavar="FILE.toml", help="the sweep file")
    run.add_argument("--out", required=True, metavar="DIR", help="the sweep folder (new or empty, or with --resume)")
    where = run.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=number("--workers"),
        default=None,
        metavar="N",
        help="worker processes of the embedded cluster (default: one per core)",
    )
    where.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        default=None,
        help="use a running Dask cluster instead of an embedded one",
    )
    again = run.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="run only the runs OUT does not hold yet")
    again.add_argument("--force", action="store_true", help="delete the rows of the sweep in OUT and start over")
    run.add_argument("--retry-failed", action="store_true", help="with --resume: also run again the failed runs")
    run.add_argument(
        "--retries",
        type=number("--retries"),
        default=3,
        metavar="N",
        help="reschedule a run whose worker died up to N times, then record it failed (default 3; "
        "an external scheduler uses its own distributed.scheduler.allowed-failures)",
    )
    run.add_argument(
        "--dashboard",
        default="127.0.0.1:8787",
        metavar="HOST:PORT|off",
        help="the embedded cluster's Dask dashboard (default 127.0.0.1:8787; needs bokeh)",
    )
    run.add_argument("--json", action="store_true", help="print machine-readable counts (JSON) at the end")
    run.set_defaults(sweep_run=_cmd_run)

    st = sub.add_parser("status", help="runs in the grid, finished, failed and missing")
    st.add_argument("out", metavar="DIR", help="the sweep folder")
    st.add_argument("--json", action="store_true", help="print JSON")
    st.set_defaults(sweep_run=_cmd_status)

    rp = sub.add_parser("report", help="Markdown table, CSV and PNG plots: mean ± 95 %% CI per cell over seeds")
    rp.add_argument("out", metavar="DIR", help="the sweep folder")
    rp.add_argument(
        "--metrics",
        default=None,
        metavar="A,B",
        help="metrics to report (default: the sweep file's metrics, else every metric)",
    )
    rp.add_argument(
        "--plot",
        default=None,
        metavar="A,B",
        help="metrics to plot (default: saturated_frames_50 and recovery_ms where reported)",
    )
    rp.add_argument("--out", dest="report_dir", default=None, metavar="DIR", help="where to write (default DIR/report)")
    rp.add_argument("--force", action="store_true", help="replace an existing report")
    rp.set_defaults(sweep_run=_cmd_report)

    sh = sub.add_parser("show", help="re-run one run deterministically in the Rerun dashboard (or --save)")
    sh.add_argument("out", metavar="DIR", help="the sweep folder")
    sh.add_argument("--run", required=True, metavar="HASH", help="the run's hash (or its first digits)")
    from necviz.dashboard.viewer_flags import add_viewer_args

    add_viewer_args(sh, ("live", "inspect", "compare"))
    sh.add_argument(
        "--speed",
        default="auto",
        help="'max', 1 (real time) or xN; default: real time when a viewer watches, max when only saving",
    )
    sh.add_argument("--force", action="store_true", help="replace an existing --save file")
    sh.set_defaults(sweep_run=_cmd_show)


def _command(args) -> int:
    return args.sweep_run(args)


COMMAND = Command(
    name="sweep",
    help="grids of closed-loop simulator runs (scenario × parameters × controller × seed) on Dask",
    description="Expands a TOML sweep file into runs, runs them on an embedded local Dask cluster (or an existing "
    "one), writes one Parquet row per run into OUT/runs/ and reports means with 95 % confidence "
    "intervals per cell.",
    add_arguments=add_arguments,
    run=_command,
)

__all__ = ["COMMAND"]
