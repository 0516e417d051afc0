"""Where the logging time of ``necviz bench pipeline`` goes: the sink taken apart, in one run.

The bench's loop (12 Mev/s, 1 ms batches, 50 fps, NEC closed loop) runs with four observers, in
alternation, ``--rounds`` times each, in one process (ratios of the same run; the machine's speed
drifts between runs):

* ``control only``: no observer;
* ``observer calls only``: the Rerun sink's observer methods on the streaming thread, with a worker
  that throws away what they queue (what the streaming thread pays to hand the sink its data);
* ``whole sink but event images`` / ``but frames`` / ``but series``: the whole sink with one part left
  out (no event window drawn, only counted / no frame encoded or logged, nor its header / scalars
  and texts dropped at each flush);
* ``whole sink``: the live sink as ``necviz live`` runs it (``SinkOptions()``), writing a file;
* ``whole sink, one rr.log per image``: the same, with each image and frame header logged by its own
  Rerun call as before 8bf0c40 (the ablation of sending them in the flushes' chunks).

The difference from the whole sink is the wall time that part costs the control loop: the
sink's worker shares the GIL with the streaming thread, so its Python and its Numba kernels that hold
the GIL come straight out of the loop's time.

    python benchmarks/sink_cost.py --json benchmarks/results/sink_cost.json
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import rerun as rr  # noqa: E402

from necviz import schema as S  # noqa: E402
from necviz.bench.timing import command_line, machine, median_table, write_result  # noqa: E402
from necviz.dashboard import pipeline_speed as bench  # noqa: E402
from necviz.dashboard.sink import RerunSink, _header_center  # noqa: E402
from necviz.layouts.views import FRAME_HEADER, FRAME_SATURATED  # noqa: E402


class ObserverCallsOnly(RerunSink):
    """The sink's observer methods as they are (the event windows counted on the streaming thread too);
    its worker drops what they queue."""

    def _run(self) -> None:
        while not self._stop:
            while self._windows:  # taken, not drawn (the streaming thread counted them into windows)
                self._batches_taken += len(self._windows.popleft()[3])
            self._frames.clear()
            self._scalar_q.clear()
            self._text_q.clear()
            self._wake.wait(self.burst_s)


class NoEventImages(RerunSink):
    """The whole sink, but every event window is only counted, never drawn."""

    def _decide_drawing(self) -> bool:
        return False


class NoFrames(RerunSink):
    """The whole sink, but no frame encoded or logged (nor its header)."""

    def _log_frame(self, lane, frame, header="", saturated="") -> None:
        pass


class NoSeries(RerunSink):
    """The whole sink, but every scalar and text dropped at each flush instead of sent."""

    def _flush_series(self, min_rows: int = 1) -> None:
        self._scalar_q.clear()
        self._text_q.clear()


class OneCallPerImage(RerunSink):
    """The whole sink as it was before 8bf0c40: a live sink logged each image and frame header with
    its own ``rr.log`` call as it was encoded (the ablation of batching them into the flushes)."""

    def _log_image(self, entity, t_us, seq, blob, media_type) -> None:
        self._set_time(t_us, seq)
        self.rec.log(entity, rr.EncodedImage(contents=blob, media_type=media_type))
        self.rec.reset_time()

    def _log_header(self, lane, frame, header, saturated) -> None:
        h, w = frame.image.shape[:2]
        self._set_time(int(frame.exposure_start_us), int(frame.sequence))
        self.rec.log(
            S.path(lane, FRAME_HEADER),
            rr.Boxes2D(centers=[_header_center(w)], half_sizes=[[w / 2, 0.5]], labels=[header], radii=[1.0]),
        )
        if saturated or lane in self._outlined:  # the outline drawn, or removed on the next frame
            if saturated:
                self._outlined.add(lane)
            else:
                self._outlined.discard(lane)
            box = {"centers": [[w / 2, h / 2]], "half_sizes": [[w / 2 - 1, h / 2 - 1]]} if saturated else {}
            self.rec.log(S.path(lane, FRAME_SATURATED), rr.Boxes2D(radii=[2.0], **box))
        self.rec.reset_time()


VARIANTS = {
    "control only": None,
    "observer calls only": ObserverCallsOnly,
    "whole sink but event images": NoEventImages,
    "whole sink but frames": NoFrames,
    "whole sink but series": NoSeries,
    "whole sink": RerunSink,
    "whole sink, one rr.log per image": OneCallPerImage,
}


def run_once(events, duration_s: float, sink_cls, folder: Path) -> tuple[float, dict]:
    """One closed-loop run of the bench's stream with ``sink_cls`` (None: no observer): wall s, sink stats."""
    r = bench.run_once(events, duration_s, 50.0, 1_000, folder if sink_cls else None, 0, sink_cls=sink_cls)
    return r["wall_s"], r.get("sink", {})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=7, help="runs of each variant, alternated (default 7)")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of stream per run (default 10)")
    ap.add_argument("--json", help="write the result here")
    args = ap.parse_args(argv)
    if not 1 <= args.rounds <= 50 or not 0 < args.duration <= 60:
        raise SystemExit("sink_cost: --rounds must lie in 1..50 and --duration in (0, 60]")
    print(f"  generating {args.duration:g} s at 12 Mev/s…", flush=True)
    events = bench.make_events(args.duration, 12.0)
    walls: dict[str, list[float]] = {name: [] for name in VARIANTS}
    logged: dict[str, list[dict]] = {name: [] for name in VARIANTS}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="necviz-sink-cost-") as tmp:
        run_once(events[: len(events) // 50], args.duration / 50, RerunSink, Path(tmp))  # kernels compiled / loaded
        for k in range(args.rounds):
            for name, cls in VARIANTS.items():
                print(
                    f"\r  round {k + 1}/{args.rounds}: {name}… ({time.perf_counter() - t0:.0f} s)", end="", flush=True
                )
                wall, stats = run_once(events, args.duration, cls, Path(tmp))
                walls[name].append(wall)
                logged[name].append({k: stats.get(k) for k in ("frames_logged", "event_images")})
    print()
    med = median_table(walls, args.duration, "variant", "control only", ("over control s", lambda w, base: w - base))
    result = {
        "command": command_line("benchmarks/sink_cost.py", ap, args),
        "duration_s": args.duration,
        "rate_mev_s": 12.0,
        "rounds": args.rounds,
        "wall_s": walls,
        "median_wall_s": med,
        "realtime_factor": {name: args.duration / w for name, w in med.items()},
        "logged": logged,
        "machine": machine(),
    }
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
