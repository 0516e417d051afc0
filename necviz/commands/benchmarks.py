"""``necviz bench estimators|sim|decode|pipeline``: the speed benchmarks (a table, optionally JSON)."""

from __future__ import annotations

from necviz.commands import Command
from necviz.commands.args import add_output_args, add_scene_args, json_output, scene_options


def _decode(args) -> int:
    from necviz.bench.decode_speed import run

    run(seconds=args.seconds, repeats=args.repeats, seed=args.seed, json_path=json_output(args))
    return 0


def _pipeline(args) -> int:
    from necviz.dashboard.pipeline_speed import run

    run(
        duration_s=args.duration,
        rate_mev_s=args.rate,
        fps=args.fps,
        batch_us=args.batch_us,
        seed=args.seed,
        repeats=args.repeats,
        json_path=json_output(args),
    )
    return 0


def _estimators(args) -> int:
    from necviz.bench.estimator_speed import EstimatorBenchOptions, run

    options = EstimatorBenchOptions(
        events=args.events,
        duration_s=args.duration,
        fps=args.fps,
        exposure_us=args.exposure_us,
        repeats=args.repeats,
        edi_samples=args.edi_samples,
        seed=args.seed,
    )
    run(options, json_path=json_output(args))
    return 0


def _sim(args) -> int:
    from necviz.bench.sim_speed import run

    run(
        duration_s=args.duration or 5.0,
        cameras=args.cameras,
        scene=scene_options(args),
        json_path=json_output(args),
        repeats=args.repeats,
    )
    return 0


def add_arguments(bench) -> None:
    from necviz.flags import number

    def B(flag):
        return number(flag, "bench")

    bsub = bench.add_subparsers(dest="bench", metavar="BENCH", required=True)

    est = bsub.add_parser(
        "estimators", help="Table 1 of the paper: EDI, mEDI, Fast-EDI, TEDI, P-TEDI and a read-only floor"
    )
    add_output_args(est)
    est.add_argument(
        "--events", type=B("--events"), default=10_000_000, help="events in the synthetic 346x260 stream (default 10M)"
    )
    est.add_argument("--duration", type=B("--duration"), default=2.0, help="stream length in seconds (default 2.0)")
    est.add_argument("--fps", type=B("--fps"), default=50.0, help="APS frame rate, 25-100 (default 50)")
    est.add_argument("--exposure-us", type=B("--exposure-us"), default=5_000, help="APS exposure (default 5000 µs)")
    est.add_argument(
        "--repeats", type=B("--repeats"), default=3, help="timed runs per method after a warm-up (default 3)"
    )
    est.add_argument(
        "--edi-samples", type=B("--edi-samples"), default=64, help="samples per exposure for EDI and mEDI (default 64)"
    )
    est.add_argument("--seed", type=number("--seed"), default=0)
    est.set_defaults(bench_run=_estimators)
    sim = bsub.add_parser("sim", help="closed-loop simulator speed: a scenario with several cameras")
    add_output_args(sim)
    add_scene_args(sim)
    sim.add_argument("--cameras", type=B("--cameras"), default=6, help="cameras sharing the scene (default 6)")
    sim.add_argument(
        "--repeats",
        type=B("--repeats"),
        default=3,
        help="timed runs (and replays from a scene cache); the median is reported",
    )
    sim.set_defaults(bench_run=_sim)
    dec = bsub.add_parser("decode", help="DAVIS stream decoder throughput on a 12 Mev/s-style stream")
    add_output_args(dec)
    dec.add_argument("--seconds", type=B("--seconds"), default=1.0, help="stream length in seconds (default 1)")
    dec.add_argument("--repeats", type=B("--repeats"), default=5, help="timed runs (default 5)")
    dec.add_argument("--seed", type=number("--seed"), default=0)
    dec.set_defaults(bench_run=_decode)
    pipe = bsub.add_parser(
        "pipeline", help="the whole dashboard path at 12 Mev/s: real-time factor and control latency"
    )
    add_output_args(pipe)
    pipe.add_argument("--duration", type=B("--duration"), default=10.0, help="stream length in seconds (default 10)")
    pipe.add_argument("--rate", type=B("--rate"), default=12.0, help="event rate in Mev/s (default 12)")
    pipe.add_argument("--fps", type=B("--fps"), default=50.0, help="frame rate (default 50)")
    pipe.add_argument("--batch-us", type=B("--batch-us"), default=1_000, help="event batch period (default 1000 µs)")
    pipe.add_argument(
        "--repeats", type=B("--repeats"), default=3, help="runs per configuration; the median is reported"
    )
    pipe.add_argument("--seed", type=number("--seed"), default=0)
    pipe.set_defaults(bench_run=_pipeline)


def _command(args) -> int:
    return args.bench_run(args)


COMMAND = Command(
    name="bench",
    help="speed benchmarks (print a table, optionally write JSON)",
    add_arguments=add_arguments,
    run=_command,
)
