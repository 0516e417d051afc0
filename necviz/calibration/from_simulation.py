"""Calibration from simulator runs: a camera driven by an exposure oracle over the calibration scene
(:mod:`necviz.drivers.sim.calibration_scene`) or presets, with exposure brackets in the scene's static
opening for the response; the packets go through a :class:`~.pairs.PairCollector`, then the fit."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, overload

import numpy as np

from necviz.calibration.fit import CalibrationOptions, CalibrationResult, _report, calibrate_collected
from necviz.calibration.pairs import PairCollector
from necviz.core.camera_profile import CameraProfile
from necviz.core.control import CameraLimits
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import DAVIS346, SensorGeometry

if TYPE_CHECKING:  # the simulator is imported on use
    from necviz.calibration.bias_settings import SettingResult, SplitCollector
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.dvs import DvsParams

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
        self.bracket_us = int(scene.bracket_us or 0) if brackets else 0
        self._mean = scene.mean_log or (lambda t: float(np.mean(scene.log_irradiance(t))))

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
    scene,
    *,
    dvs=None,
    aps=None,
    crf: CameraResponse | None = None,
    seed: int = 0,
    brackets: bool = True,
    dvs_changes=(),
    timeline=None,
):
    """Packets (events, markers, frames) of one simulated camera driven by :class:`ExposureOracle`.

    The command for each frame is issued at the previous exposure start (the simulator's latency
    is far shorter than a frame interval), so every frame gets the oracle's exposure.

    ``dvs_changes``: ``(seconds, key, value)`` DVS controls written to the simulated camera's biases at those
    scene times (as ``--dvs`` does; :mod:`necviz.core.biases` maps a request to bias words, the simulator takes the
    pixel they give). Each takes effect at the simulator's next DVS step; ``timeline``
    (:class:`~.bias_settings.BiasTimeline`) is told when, with the settings and the simulated pixel's true
    thresholds, before any packet after it is yielded.
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
    changes = sorted(dvs_changes or (), key=lambda c: float(c[0]))
    state, waiting = (_bias_state(rig.dvs_params) if changes else None), False
    k = 0
    for _, packet in rig.packets():
        if changes or waiting:
            t_now = rig.now_us
            while changes and changes[0][0] * 1e6 <= t_now:  # due: written to the biases together
                _, key, value = changes.pop(0)
                assert state is not None
                change = state.request(key, value)
                rig.set_dvs_biases(change.words())
                state.apply(change)
                waiting = True
            t_eff = rig.dvs_applied_us() if waiting else None
            if t_eff is not None:
                waiting = False
                if timeline is not None:
                    timeline.add(t_eff, {**_settings(state), "truth": _truth(rig.dvs_params)})
        if isinstance(packet, ExposureMarker) and packet.kind == "start":
            k += 1
            exp_us, gain = oracle(packet.t_us + aps.frame_interval_us, k)
            rig.set_exposure("cal", exp_us, gain)
        yield packet


def _bias_state(pixel):
    """The bias model for the simulated pixel ``pixel`` at libcaer's default biases: a request for
    ``c_on = 0.15`` gives the pixel's mean ON threshold 0.15 (the nearest the biases reach)."""
    from necviz.core.biases import BiasModel, DvsBiases, DvsSettings, DvsState, physical_settings

    phys = physical_settings(DvsBiases.defaults("DAVIS346"))
    ref = DvsSettings(pixel.c_on, pixel.c_off, pixel.refractory_us, pixel.cutoff_hz or phys.bandwidth_hz)
    return DvsState(BiasModel("DAVIS346", ref))


def _settings(state) -> dict:
    return state.settings().as_dict()


def _truth(pixel) -> dict:
    """The simulated pixel's true mean thresholds, refractory period and bandwidth."""
    return {
        "c_on": pixel.c_on,
        "c_off": pixel.c_off,
        "refractory_us": pixel.refractory_us,
        "cutoff_hz": pixel.cutoff_hz,
    }


def make_sim_scene(name: str, sensor: SensorGeometry, duration_s: float | None, seed: int):
    """The calibration scene (``"calibration"``) or an evaluation preset by name."""
    from necviz.drivers.sim.calibration_scene import CALIBRATION_SCENE, CalibrationScene

    dur = None if duration_s is None else int(round(duration_s * 1e6))
    if name == CALIBRATION_SCENE:
        return CalibrationScene(sensor=sensor, duration_us=dur, seed=seed)
    from necviz.drivers.sim.scenes import make_scenario

    return make_scenario(name, sensor=sensor, duration_us=dur, seed=seed)


@dataclass(frozen=True)
class CalibrationSimulation:
    """The simulator runs a calibration fits on: every scenario x seed, one simulated camera each
    (validated here, once).

    Parameters
    ----------
    scenarios : str or sequence of str
        ``"calibration"`` (the held-out calibration scene) and/or preset names; kept as a tuple.
    seeds : int or sequence of int
        The seeds each scenario runs with; kept as a tuple.
    duration_s : float, optional
        Simulated seconds per run (0..600; ``None``: the scene's own duration).
    sensor : SensorGeometry
        The simulated sensor (default: DAVIS346).
    dvs, aps : DvsParams, ApsParams, optional
        The simulated camera's event and frame models (default: the simulated DAVIS346).
    crf : CameraResponse, optional
        The response the simulator renders frames with (default: the DAVIS346-like curve).
    dvs_changes : sequence of (seconds, key, value)
        DVS bias controls written during each run at those scene times (``--dvs-at``;
        :func:`simulate_calibration_stream`): the data of several bias settings, for a fit per setting.

    Raises
    ------
    ParameterError
        No scenario or seed, an unknown scenario, a negative or non-integer seed, or a duration out of range.
    """

    scenarios: tuple[str, ...] = ("calibration",)
    seeds: tuple[int, ...] = (0,)
    duration_s: float | None = None
    sensor: SensorGeometry = DAVIS346
    dvs: DvsParams | None = None
    aps: ApsParams | None = None
    crf: CameraResponse | None = None
    dvs_changes: tuple = ()

    def __post_init__(self) -> None:
        from necviz.drivers.sim.calibration_scene import CALIBRATION_SCENE
        from necviz.drivers.sim.scenes import SCENARIOS

        scenarios = (self.scenarios,) if isinstance(self.scenarios, str) else tuple(self.scenarios)
        seeds = (self.seeds,) if isinstance(self.seeds, (int, np.integer)) else tuple(self.seeds)
        if not scenarios or not seeds:
            raise ParameterError("give at least one scenario and one seed")
        bad = [s for s in scenarios if s != CALIBRATION_SCENE and s not in SCENARIOS]
        if bad:
            raise ParameterError(
                f"--sim: unknown scenario(s) {', '.join(map(str, bad))}; available: "
                f"{CALIBRATION_SCENE}, {', '.join(sorted(SCENARIOS))}"
            )
        if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0 for v in seeds):
            raise ParameterError(f"seeds must be whole numbers >= 0, got {list(seeds)}")
        d = self.duration_s
        if d is not None and not (isinstance(d, (int, float)) and 0 < d <= 600):
            raise ParameterError(f"--duration must lie in (0, 600] s, got {d!r}")
        if not isinstance(self.sensor, SensorGeometry):
            raise ParameterError(f"sensor must be a SensorGeometry, got {type(self.sensor).__name__}")
        from necviz.calibration.bias_settings import parse_change

        changes = tuple(parse_change(f"{t}:{k}={v}") for t, k, v in self.dvs_changes or ())
        object.__setattr__(self, "dvs_changes", changes)
        object.__setattr__(self, "scenarios", scenarios)
        object.__setattr__(self, "seeds", tuple(int(v) for v in seeds))


@overload
def calibrate_from_simulation(
    simulation: CalibrationSimulation | None = None,
    options: CalibrationOptions | None = None,
    *,
    progress=None,
    bias_setting: None = None,
) -> CalibrationResult: ...


@overload
def calibrate_from_simulation(
    simulation: CalibrationSimulation | None = None,
    options: CalibrationOptions | None = None,
    *,
    progress=None,
    bias_setting: int | str,
) -> list[SettingResult]: ...


def calibrate_from_simulation(
    simulation: CalibrationSimulation | None = None,
    options: CalibrationOptions | None = None,
    *,
    progress=None,
    bias_setting: int | str | None = None,
) -> CalibrationResult | list[SettingResult]:
    """Calibrate from simulator runs: every scenario x seed, one camera driven by :class:`ExposureOracle`.

    The profile's limits are the simulated camera's.

    Parameters
    ----------
    simulation : CalibrationSimulation, optional
        The runs (default: ``CalibrationSimulation()``, the calibration scene, seed 0, DAVIS346).
    options : CalibrationOptions, optional
        What to fit, from which start and on which pairs (default: ``CalibrationOptions()``; the
        starting profile defaults to one of ``simulation.sensor``). Its ``max_event_rate="auto"``
        is the simulated sensor's bus ceiling.
    progress : callable, optional
        ``progress(text)`` gets a status line now and then.

    bias_setting : int or "all", optional
        Fit one bias setting of ``simulation.dvs_changes`` (0: the simulator's default biases) or each one
        (:mod:`.bias_settings`); ``None``: all the data in one fit.

    Returns
    -------
    CalibrationResult
        Or, with ``bias_setting``, a list of :class:`~.bias_settings.SettingResult` (one per setting fitted).

    Raises
    ------
    ParameterError
        Arguments of the wrong type, or runs without a qualifying frame pair.
    """
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.dvs import DvsParams

    sim = CalibrationSimulation() if simulation is None else simulation
    if not isinstance(sim, CalibrationSimulation):
        raise ParameterError(f"simulation must be a CalibrationSimulation, got {type(sim).__name__}")
    opts = CalibrationOptions() if options is None else options
    if not isinstance(opts, CalibrationOptions):
        raise ParameterError(f"options must be a CalibrationOptions, got {type(opts).__name__}")
    scenarios, seeds, duration_s, sensor = list(sim.scenarios), list(sim.seeds), sim.duration_s, sim.sensor
    aps = sim.aps or ApsParams()
    dvs = sim.dvs or DvsParams()
    sim_crf = sim.crf or default_davis346()
    base = opts.profile or CameraProfile(sensor=sensor)
    scenes = [(sc, sd, make_sim_scene(sc, sensor, duration_s, int(sd))) for sc in scenarios for sd in seeds]
    split = timeline = None
    if bias_setting is not None:
        from necviz.calibration.bias_settings import BiasTimeline, SplitCollector

        timeline = BiasTimeline()
        timeline.settings[0] = {
            "c_on": dvs.c_on,
            "c_off": dvs.c_off,
            "refractory_us": dvs.refractory_us,
            "bandwidth_hz": dvs.cutoff_hz,
            "truth": _truth(dvs),
        }
        split = SplitCollector(timeline, lambda: PairCollector(base.crf, opts.selection, opts.collection))
    col = PairCollector(base.crf, opts.selection, opts.collection)
    target: PairCollector | SplitCollector = col if split is None else split
    t_wall, last = time.perf_counter(), 0.0
    for sc, sd, scene in scenes:
        if timeline is not None:
            timeline.restart()
        target.begin(f"sim:{sc}:seed{sd}")
        stream = simulate_calibration_stream(
            scene, dvs=dvs, aps=aps, crf=sim_crf, seed=int(sd), dvs_changes=sim.dvs_changes, timeline=timeline
        )
        for packet in stream:
            target.feed(packet)
            if isinstance(packet, Frame):
                now = time.perf_counter()
                if now - last > 0.5:
                    last = now
                    _report(
                        progress,
                        f"simulating {sc} seed {sd}: {packet.exposure_end_us / 1e6:.2f}/"
                        f"{scene.duration_us / 1e6:g} s, {_kept(target)} pairs kept ({now - t_wall:.0f} s)",
                    )
    target.finish()
    limits = CameraLimits(float(aps.exposure_min_us), float(aps.exposure_max_us), float(aps.gain_max))
    described = {
        "scenarios": scenarios,
        "seeds": [int(s) for s in seeds],
        "duration_s": [s.duration_us / 1e6 for _, _, s in scenes][0],
        "sensor": f"{sensor.width}x{sensor.height}",
        "dvs": dvs.as_dict(),
        "exposure": "oracle (the scene's mean ln L), brackets in the static opening",
        **({"dvs_changes": [list(c) for c in sim.dvs_changes]} if sim.dvs_changes else {}),
    }
    rate = dvs.max_event_rate if opts.max_event_rate == "auto" else opts.max_event_rate
    opts = replace(opts, profile=base, max_event_rate=rate)
    if split is not None:
        from necviz.calibration.bias_settings import fit_settings

        return fit_settings(
            split, bias_setting, opts, limits=limits, extra={"simulation": described}, progress=progress
        )
    return calibrate_collected(col, opts, limits=limits, extra={"simulation": described}, progress=progress)


def _kept(col) -> int:
    """Pairs kept so far by a collector, or by every setting's collector."""
    cols = getattr(col, "collectors", None)
    return sum(len(c.pairs) for c in cols.values()) if cols is not None else len(col.pairs)
