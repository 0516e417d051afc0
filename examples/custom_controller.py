#!/usr/bin/env python
"""A custom exposure controller compared in closed loop with NEC and Navid on a simulated tunnel exit.

``MeanIntensityController`` subclasses ``necviz.core.control.Controller``: on every frame it moves
the log exposure-gain product ``ln(T K)`` a fraction ``k`` of the way from the frame's mean digital
value to the goal intensity, through the camera response (``g(I_opt) - g(mean Z)``), exposure first,
then gain. It sees frames only, so it reacts one frame late and at most ~1.4 ln per frame when the
image is white. All three controllers run on one ``SimRig`` (one scene, one event stream, one
camera each) through the same ``Pipeline`` as ``necviz compare``; the per-frame rates come from its
``Telemetry`` and the table from ``necviz.core.metrics.summarise``.

To use it with ``necviz compare --controllers nec,navid,meanprop``, register it:
``register_controller("meanprop", MeanIntensityController, build)`` with a builder that gets the
camera's context (limits, starting exposure, camera response) and the controller's options; from
then on ``make_controller`` and every command know it (see ``--via-compare``).

usage: python examples/custom_controller.py [--duration-s 0.8] [--seed 1] [--k 0.8] [--via-compare]
"""

import argparse
import math

from necviz.core import Frame, SensorGeometry, default_davis346
from necviz.core.control import CameraLimits, Controller, ExposureCommand, make_controller, register_controller
from necviz.core.errors import ParameterError
from necviz.core.metrics import summarise
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.rig import SimRig
from necviz.drivers.sim.scenes import make_scenario
from necviz.pipeline import Lane, Pipeline


class MeanIntensityController(Controller):
    """Proportional control of the mean frame intensity: ``ln(T K) += k (g(I_opt) - g(mean Z))``."""

    name = "meanprop"

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0, crf=None, k: float = 0.8):
        super().__init__(limits, exposure_us, gain)
        self.crf = crf or default_davis346()
        if not 0 < k <= 1:
            raise ParameterError(f"k must lie in (0, 1], got {k}")
        self.k = float(k)

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)  # records the exposure and gain this frame was taken with
        step_ln = self.k * (self.crf.goal_log_exposure - self.crf.log_exposure(float(frame.image.mean())))
        if abs(step_ln) < 0.05:  # dead band: no flicker from tiny corrections
            return None
        product_us = self.exposure_us * self.gain * math.exp(step_ln)
        exposure_us = min(product_us, self.limits.exposure_max_us)  # exposure first, then gain
        exposure_us, gain = self.limits.clamp(exposure_us, product_us / exposure_us)
        return ExposureCommand(exposure_us, gain, int(self.now_us), self.name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=0.8, help="simulated time in s (0.2..10)")
    ap.add_argument("--seed", type=int, default=1, help="scene and noise seed (>= 0)")
    ap.add_argument("--k", type=float, default=0.8, help="fraction of the log error corrected per frame, (0, 1]")
    ap.add_argument(
        "--via-compare",
        action="store_true",
        help="register the controller and run necviz.commands.compare.run instead (full 346x260, slower)",
    )
    args = ap.parse_args()
    if not (0.2 <= args.duration_s <= 10 and args.seed >= 0 and 0 < args.k <= 1):
        ap.error("need 0.2 <= --duration-s <= 10, --seed >= 0 and 0 < --k <= 1")
    names = ["nec", "navid", MeanIntensityController.name]
    if args.via_compare:
        import necviz

        register_controller(  # now make_controller (and so compare) knows it
            MeanIntensityController.name,
            MeanIntensityController,
            lambda ctx, options: MeanIntensityController(ctx.limits, ctx.exposure_us, ctx.gain, crf=ctx.crf, k=args.k),
        )
        necviz.run_compare(
            necviz.CompareOptions(
                necviz.SceneOptions("tunnel_exit", seed=args.seed, duration_s=args.duration_s), names, sift=False
            )
        )
        return

    sensor = SensorGeometry(173, 130)  # half the DAVIS346 resolution: same optics, 4x faster
    scene = make_scenario("tunnel_exit", sensor=sensor, duration_us=int(args.duration_s * 1e6), seed=args.seed)
    aps, crf = ApsParams(), default_davis346()
    rig = SimRig(scene, names, aps=aps, crf=crf, seed=args.seed)  # every camera starts at the same exposure
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    start_us = rig.cams["nec"].exposure_us
    rate = rig.camera_info.event_rate_max  # the source's event bus ceiling, which NEC's escape rule reads
    ctrls = {
        n: make_controller(n, sensor=sensor, limits=limits, exposure_us=start_us, crf=crf, event_rate_max=rate)
        for n in names[:2]
    }
    ctrls[names[2]] = MeanIntensityController(limits, start_us, crf=crf, k=args.k)
    # events go to every lane, frames to their own camera's lane; commands back to that camera
    pipe = Pipeline(rig, [Lane(n, ctrls[n]) for n in names])
    pipe.run().finish()
    steps_us = [c.t_us for c in scene.changes]
    print(
        f"tunnel_exit, {sensor.width}x{sensor.height} px, {args.duration_s:g} s, seed {args.seed}, "
        f"exit at {steps_us[0] / 1e3:.0f} ms, start exposure {start_us:.0f} µs"
    )
    print(
        f"{'controller':10s} {'frames':>6s} {'sat>50%':>7s} {'sat>10%':>7s} {'mean over':>9s} {'mean under':>10s} "
        f"{'recovery ms':>11s}"
    )
    for n in names:
        frames = pipe.telemetry[n].table
        m = summarise(
            frames.column("exposure_start_us"),
            frames.column("over_exposed_rate"),
            frames.column("under_exposed_rate"),
            steps_us,
            end_us=scene.duration_us,
        )
        rec = "never" if m.recovery_ms is None else f"{m.recovery_ms:.0f}"
        print(
            f"{n:10s} {m.frames:6d} {m.saturated_frames_50:7d} {m.saturated_frames_10:7d} "
            f"{m.mean_over_exposed_rate:9.3f} {m.mean_under_exposed_rate:10.3f} {rec:>11s}"
        )


if __name__ == "__main__":
    main()
