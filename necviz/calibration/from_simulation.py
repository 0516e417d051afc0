"""Calibration from simulator runs: a camera driven by an exposure oracle over the calibration scene
(:mod:`necviz.drivers.sim.calibration_scene`) or presets, with exposure brackets in the scene's static
opening for the response; the packets go through a :class:`~.pairs.PairCollector`, then the fit."""

from __future__ import annotations

import math
import time

import numpy as np

from necviz.calibration.fit import (
    DEFAULT_F_SCALE,
    DEFAULT_LOSS,
    DEFAULT_SLOW_RATE,
    CalibrationResult,
    _report,
    calibrate_collected,
)
from necviz.calibration.pairs import DEFAULTS, _collector
from necviz.core.camera_profile import CameraProfile
from necviz.core.control import CameraLimits
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import DAVIS346, SensorGeometry

BRACKET_OFFSETS = (-2.4, -1.6, -0.8, 0.0, 0.8, 1.6, 2.4)  # ln exposure offsets in the static opening


class ExposureOracle:
    """The exposure a perfect auto-exposure would set for a frame starting at ``start_us``.

    ``T K = exp(g(I_opt) - m(start + T/2))`` with ``m`` the scene's mean ``ln L`` (exact: the
    simulator knows the scene), iterated three times; exposure first, gain beyond
    ``exposure_max_us``. During the scene's static opening (``scene.bracket_us``, if any) the
    products step through :data:`BRACKET_OFFSETS` (exposure brackets for the response).
    """

    def __init__(self, scene, crf: CameraResponse, aps, brackets: bool = True):
        self.scene, self.crf, self.aps = scene, crf, aps
        self.bracket_us = int(getattr(scene, "bracket_us", 0) or 0) if brackets else 0
        self._mean = getattr(scene, "mean_log", None) or (lambda t: float(np.mean(scene.log_irradiance(t))))

    def __call__(self, start_us: int, k: int) -> tuple[float, float]:
        aps = self.aps
        goal = self.crf.goal_log_exposure
        total = 0.25 * aps.exposure_max_us
        for _ in range(3):
            mid = start_us + min(total, aps.exposure_max_us) / 2
            total = math.exp(goal - self._mean(min(mid, self.scene.duration_us))) * 1e6
            total = min(max(total, aps.exposure_min_us), aps.exposure_max_us * aps.gain_max)
        if start_us < self.bracket_us:
            total = min(
                max(total * math.exp(BRACKET_OFFSETS[k % len(BRACKET_OFFSETS)]), aps.exposure_min_us),
                aps.exposure_max_us * aps.gain_max,
            )
        gain = max(1.0, total / aps.exposure_max_us)
        return total / gain, gain


def simulate_calibration_stream(
    scene, *, dvs=None, aps=None, crf: CameraResponse | None = None, seed: int = 0, brackets: bool = True
):
    """Packets (events, markers, frames) of one simulated camera driven by :class:`ExposureOracle`.

    The command for each frame is issued at the previous exposure start (the simulator's latency
    is far shorter than a frame interval), so every frame gets the oracle's exposure.
    """
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.rig import RigOptions, SimRig

    aps = aps or ApsParams()
    crf = crf or default_davis346()
    oracle = ExposureOracle(scene, crf, aps, brackets)
    first = 1_000
    t0, k0 = oracle(first, 0)
    rig = SimRig(
        scene, {"cal": (t0, k0)}, dvs=dvs, aps=aps, crf=crf, seed=seed, options=RigOptions(first_start_us=first)
    )
    k = 0
    for _, packet in rig.packets():
        if isinstance(packet, ExposureMarker) and packet.kind == "start":
            k += 1
            exp_us, gain = oracle(packet.t_us + aps.frame_interval_us, k)
            rig.set_exposure("cal", exp_us, gain)
        yield packet


def make_sim_scene(name: str, sensor: SensorGeometry, duration_s: float | None, seed: int):
    """The calibration scene (``"calibration"``) or an evaluation preset by name."""
    from necviz.drivers.sim.calibration_scene import CALIBRATION_SCENE, CalibrationScene

    dur = None if duration_s is None else int(round(duration_s * 1e6))
    if name == CALIBRATION_SCENE:
        return CalibrationScene(sensor=sensor, duration_us=dur, seed=seed)
    from necviz.drivers.sim.scenes import make_scenario

    return make_scenario(name, sensor=sensor, duration_us=dur, seed=seed)


def calibrate_from_simulation(
    scenarios=("calibration",),
    seeds=(0,),
    duration_s: float | None = None,
    *,
    sensor: SensorGeometry = DAVIS346,
    dvs=None,
    aps=None,
    sim_crf: CameraResponse | None = None,
    profile: CameraProfile | None = None,
    init: TediParams | None = None,
    fit="all",
    crf: str = "auto",
    name: str | None = None,
    max_event_rate="auto",
    slow_rate: float = DEFAULT_SLOW_RATE,
    loss: str = DEFAULT_LOSS,
    f_scale: float = DEFAULT_F_SCALE,
    progress=None,
    max_nfev: int = 200,
    **selection,
) -> CalibrationResult:
    """Calibrate from simulator runs: every scenario x seed, one camera driven by :class:`ExposureOracle`.

    ``scenarios``: ``"calibration"`` (the held-out calibration scene) and/or preset names;
    ``dvs``/``aps``/``sim_crf``: the simulated camera (defaults: the simulated DAVIS346). The
    profile's limits are the simulated camera's. Other arguments as
    :func:`calibrate_from_recordings`.
    """
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.dvs import DvsParams

    scenarios = [scenarios] if isinstance(scenarios, str) else list(scenarios)
    seeds = [seeds] if isinstance(seeds, (int, np.integer)) else list(seeds)
    if not scenarios or not seeds:
        raise ParameterError("give at least one scenario and one seed")
    if duration_s is not None and not (isinstance(duration_s, (int, float)) and 0 < duration_s <= 600):
        raise ParameterError(f"--duration must lie in (0, 600] s, got {duration_s!r}")
    aps = aps or ApsParams()
    dvs = dvs or DvsParams()
    sim_crf = sim_crf or default_davis346()
    base = profile or CameraProfile(sensor=sensor)
    unknown = set(selection) - {"reference", *DEFAULTS}
    if unknown:
        raise ParameterError(f"unknown selection option(s): {', '.join(sorted(unknown))}")
    scenes = [(sc, sd, make_sim_scene(sc, sensor, duration_s, int(sd))) for sc in scenarios for sd in seeds]
    col = _collector(base, dict(selection))
    t_wall, last = time.perf_counter(), 0.0
    for sc, sd, scene in scenes:
        col.begin(f"sim:{sc}:seed{sd}")
        for packet in simulate_calibration_stream(scene, dvs=dvs, aps=aps, crf=sim_crf, seed=int(sd)):
            col.feed(packet)
            if isinstance(packet, Frame):
                now = time.perf_counter()
                if now - last > 0.5:
                    last = now
                    _report(
                        progress,
                        f"simulating {sc} seed {sd}: {packet.exposure_end_us / 1e6:.2f}/"
                        f"{scene.duration_us / 1e6:g} s, {len(col.pairs)} pairs kept ({now - t_wall:.0f} s)",
                    )
    col.finish()
    limits = CameraLimits(float(aps.exposure_min_us), float(aps.exposure_max_us), float(aps.gain_max))
    sim = {
        "scenarios": scenarios,
        "seeds": [int(s) for s in seeds],
        "duration_s": [s.duration_us / 1e6 for _, _, s in scenes][0],
        "sensor": f"{sensor.width}x{sensor.height}",
        "dvs": dvs.as_dict(),
        "exposure": "oracle (the scene's mean ln L), brackets in the static opening",
    }
    return calibrate_collected(
        col,
        base=base,
        init=init,
        fit=fit,
        crf_mode=crf,
        name=name,
        limits=limits,
        max_event_rate=dvs.max_event_rate if max_event_rate == "auto" else max_event_rate,
        slow_rate=slow_rate,
        loss=loss,
        f_scale=f_scale,
        extra={"simulation": sim},
        progress=progress,
        max_nfev=max_nfev,
    )
