"""``necviz calibrate``: fit a camera profile (TEDI's six parameters, and the response where brackets exist).

The TEDI parameters ``p = {c+, c-, a+, b+, a-, b-}`` are fitted by frame-to-frame consistency
(Eq. 7 of Lin et al., "Neuromorphic exposure control", with squared residuals): for consecutive
frames ``i-1, i`` and a common reference ``g`` (the exposure start of frame ``i-1``), minimise
``Σ_i Σ_x (ln L_i(g,x) - ln L_{i-1}(g,x))²`` where each ``ln L`` is Eq. 5 applied to one frame
and the events between it and ``g`` (:mod:`necviz.core.tedi`, SciPy least squares). Where the
data hold exposure brackets of a static scene, the camera response ``g(Z)`` is fitted first by
Debevec & Malik (1997) and the TEDI fit uses it.

Data: recordings in any format :func:`necviz.drivers.replay.open_recording` reads, or simulator
runs (:func:`simulate_calibration_stream`: the calibration scene of
:mod:`necviz.drivers.sim.calibration_scene`, or a preset, driven by an exposure oracle).
Both are consumed as one stream of packets by :class:`PairCollector`.

**Pair selection** (:class:`PairCollector`, :func:`necviz.core.tedi.prepare_pair`):

* frames in stream order, each starting after the previous one and at most ``max_gap_us`` after
  its end (no pairs across pauses);
* a pixel is used when it is valid (digital value 9..250) in both frames, its frame-measured
  change ``|ln Lbar_i - ln Lbar_j|`` is at least ``min_change`` (default 0.5 ln units, about two
  thresholds) and — the *continuation rule* — that change has the polarity of the pixel's last
  event before the pair. Pixels that did not change carry no information about ``c``; a DVS
  pixel loses about half an event at a reversal (hysteresis), which Eq. 7 would read as larger
  thresholds. Both rules use the frames and the history before the pair, never the pair's own
  event counts (selecting on those would bias the thresholds);
* frame ``i`` pairs with the nearest earlier frame ``j = i-1, ..., i-max_lag`` (default 8) that
  gives at least ``min_pixels`` (200) such pixels: Eq. 7's consecutive pairs when the scene
  changed enough between two frames, a longer baseline for slow changes (one event per pixel
  biases the least-squares thresholds low). Pairs never overlap; at most ``max_pixels`` (5000)
  pixels per pair are kept (an even subsample).

**Fit** (:func:`calibrate_collected`): thresholds on the pairs that stayed below the sensor's bus
ceiling, then the compensation with the thresholds fixed on all pairs, its knee ``b/a`` bounded
below by ``slow_rate``.

**Bounded memory**: events are buffered only from the exposure start of the oldest frame that
may still pair (``max_lag`` frame intervals); each used pair keeps the events of its used pixels
only (13 bytes each) and two bytes per pixel. When more than ``max_pairs`` pairs qualify or they exceed ``max_bytes``, every
other stored pair is dropped and from then on only every second qualifying pair is kept (then
every fourth, ...): the pairs stay spread evenly over the data and the memory stays below the
budget however long the recordings are.

**Exposure brackets**: runs of consecutive frames with (almost) no events between them
(``static_events`` per pixel) whose well-exposed pixels agree on the irradiance form a static
group (:meth:`PairCollector._brackets`); the group with the most distinct exposure-gain
products (at least 3, spanning at least 4x) feeds Debevec-Malik.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from .core.control import CameraLimits
from .core.crf import CameraResponse, debevec_malik, default_davis346
from .core.errors import EventFormatError, ParameterError
from .core.event_model import TediParams
from .core.events import EVENT_DTYPE
from .core.frames import ExposureMarker, Frame
from .core.profile import CameraProfile, load_profile
from .core.sensor import DAVIS346, SensorGeometry
from .core.tedi import (PARAM_NAMES, REFERENCES, CalibrationPair, TediCalibration, fit_tedi_pairs, pair_residuals,
                        prepare_pair, update_last_polarity)

__all__ = ["CalibrationResult", "PairCollector", "add_parser", "calibrate_from_recordings",
           "calibrate_from_simulation", "default_sim_profile", "parse_seeds", "run", "simulate_calibration_stream",
           "SIM_PROFILE", "SIM_CALIBRATION"]

#: The shipped profile of the simulated DAVIS346 (package data).
SIM_PROFILE = "davis346-sim.json"

#: How the shipped profile was made (the README repeats it): the calibration scene only, which no
#: evaluation uses; its seeds and duration.
SIM_CALIBRATION = {"scenarios": ["calibration"], "seeds": [0, 1, 2], "duration_s": 6.0}

DEFAULTS = {"min_change": 0.5, "min_pixels": 200, "max_pixels": 5_000, "max_pairs": 200,
            "max_bytes": 400_000_000, "max_gap_us": 1_000_000, "max_lag": 8, "static_events": 0.05,
            "continuation": True}

FIT_CHOICES = {"all": PARAM_NAMES, "c": ("c_on", "c_off")}

#: Lower bound of the compensation knee b/a (events per pixel per second): below it a pixel's events
#: are taken at face value. A third of the DAVIS346's whole-array bus ceiling (12 Mev/s / 89,960
#: pixels = 133 ev/s per pixel), far below its refractory limit (~10 kev/s).
DEFAULT_SLOW_RATE = 50.0

#: Bus ceilings (events/s) assumed for recordings of known sensors (``--max-event-rate auto``).
KNOWN_EVENT_RATES = {(346, 260): 12e6, (240, 180): 12e6}

#: Loss of the least-squares fit (SciPy ``least_squares``): see :func:`calibrate_collected`.
DEFAULT_LOSS = "linear"
DEFAULT_F_SCALE = 0.25


def default_sim_profile() -> CameraProfile:
    """The camera profile calibrated on the simulated DAVIS346 (``necviz/profiles/davis346-sim.json``).

    Made by ``necviz calibrate --sim calibration --seeds 0..2 --duration 6`` on the default
    simulator (:class:`~necviz.drivers.sim.dvs.DvsParams`, :class:`~necviz.drivers.sim.aps.ApsParams`);
    see :data:`SIM_CALIBRATION`. The calibration scene is used by no evaluation.
    """
    ref = resources.files("necviz") / "profiles" / SIM_PROFILE
    with resources.as_file(ref) as path:
        return load_profile(path)


# ---------------------------------------------------------------------------------------------------
# the stream consumer
# ---------------------------------------------------------------------------------------------------


class _Recent:
    """A frame kept for pairing, with the arrays the selection needs (computed once)."""

    __slots__ = ("frame", "log_lbar", "valid", "last_polarity", "used")

    def __init__(self, frame: Frame, crf: CameraResponse, last_polarity: np.ndarray):
        img = frame.image.ravel()
        self.frame = frame
        self.log_lbar = np.asarray(crf.log_irradiance(img, frame.exposure_us, frame.gain), np.float32)
        self.valid = (img >= crf.valid_min) & (img <= crf.valid_max)
        self.last_polarity = last_polarity
        self.used = False  # already the earlier frame of a pair


def _well(frame: Frame) -> np.ndarray:
    img = frame.image.ravel()
    return (img >= 30) & (img <= 230)


class PairCollector:
    """Consume packets in stream order (event batches, exposure markers, frames) and keep the frame
    pairs Eq. 7 will use, plus the best static exposure-bracket group (module docstring).

    ``crf``: the response used to select pixels (the fit may use a refined one). Call
    :meth:`begin` before each recording or run (forgets earlier frames), :meth:`feed` for
    every packet, :meth:`finish` at the end. Counters (``frames``, ``considered``, ``rejected``
    by reason, ``qualifying``, ``stride``, ``lags``) describe what happened.

    Pairing: for each new frame ``i`` the earlier frames ``i-1, i-2, ... i-max_lag`` are tried in
    that order and the first with at least ``min_pixels`` usable pixels forms the pair; pairs never
    overlap (the earlier frame of a pair is never older than the later frame of the previous one),
    so a change is not counted again from every frame of the hold that follows it.
    ``max_lag = 1`` is Eq. 7's consecutive pairs; a longer baseline lets slow changes accumulate
    several events per pixel, which the thresholds need (with about one event per pixel the
    least-squares thresholds come out low).
    """

    def __init__(self, crf: CameraResponse, *, reference: str = "previous_start",
                 min_change: float = DEFAULTS["min_change"], min_pixels: int = DEFAULTS["min_pixels"],
                 max_pixels: int = DEFAULTS["max_pixels"], max_pairs: int = DEFAULTS["max_pairs"],
                 max_bytes: int = DEFAULTS["max_bytes"], max_gap_us: int = DEFAULTS["max_gap_us"],
                 max_lag: int = DEFAULTS["max_lag"], static_events: float = DEFAULTS["static_events"],
                 continuation: bool = DEFAULTS["continuation"], max_buffer_events: int = 30_000_000):
        if reference not in REFERENCES:
            raise ParameterError(f"reference must be one of {', '.join(REFERENCES)}, got {reference!r}")
        for name, v, lo in (("min_pixels", min_pixels, 1), ("max_pixels", max_pixels, 1), ("max_pairs", max_pairs, 2),
                            ("max_bytes", max_bytes, 1), ("max_gap_us", max_gap_us, 1), ("max_lag", max_lag, 1),
                            ("max_buffer_events", max_buffer_events, 1)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
        if max_lag > 50:
            raise ParameterError(f"max_lag must be at most 50 frames, got {max_lag}")
        for name, v in (("min_change", min_change), ("static_events", static_events)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ParameterError(f"{name} must be a number >= 0, got {v!r}")
        self.crf = crf
        self.reference = reference
        self.min_change, self.min_pixels, self.max_pixels = float(min_change), int(min_pixels), int(max_pixels)
        self.max_pairs, self.max_bytes, self.max_gap_us = int(max_pairs), int(max_bytes), int(max_gap_us)
        self.max_lag = int(max_lag)
        self.static_events = float(static_events)
        self.continuation = bool(continuation)
        self.max_buffer_events = int(max_buffer_events)
        self.shape: tuple[int, int] | None = None
        self.pairs: list[CalibrationPair] = []
        self.frames = 0
        self.events = 0
        self.considered = 0
        self.qualifying = 0
        self.stride = 1
        self.lags: dict[int, int] = {}
        self.rejected = {"gap_or_order": 0, "too_few_pixels": 0}
        self.sources: list[str] = []
        self.best_brackets: list[tuple[np.ndarray, float]] | None = None
        self._source = ""
        self._recent: list[_Recent] = []
        self._chunks: list[np.ndarray] = []
        self._buffered = 0
        self._group: list[tuple[np.ndarray, float]] = []
        self._bytes = 0
        self._run_last: np.ndarray | None = None  # polarity of each pixel's last event before _run_t
        self._run_t = -(1 << 62)

    # -- stream ------------------------------------------------------------------------------------
    def begin(self, source: str) -> None:
        """Start a new recording or run: earlier frames, buffered events and event history are forgotten."""
        self._close_group()
        self._source = source
        self.sources.append(source)
        self._recent = []
        self._chunks = []
        self._buffered = 0
        self._run_t = -(1 << 62)
        if self._run_last is not None:
            self._run_last[:] = 0

    def feed(self, packet) -> None:
        if isinstance(packet, np.ndarray):
            if packet.dtype != EVENT_DTYPE:
                return
            if packet.size:
                self._chunks.append(packet)
                self._buffered += packet.size
                self.events += packet.size
                if self._buffered > self.max_buffer_events:  # frames too far apart: start over
                    if self._recent:
                        self.rejected["gap_or_order"] += 1
                    self._recent = []
                    self._close_group()
                    self._drop_before(int(packet["t"][-1]) + 1)
        elif isinstance(packet, ExposureMarker):
            if packet.kind == "start" and not self._recent:
                self._drop_before(packet.t_us)
        elif isinstance(packet, Frame):
            self._on_frame(packet)

    def finish(self) -> None:
        self._close_group()
        self._chunks, self._buffered, self._recent = [], 0, []

    # -- internals ---------------------------------------------------------------------------------
    def _events(self) -> np.ndarray:
        if not self._chunks:
            return np.zeros(0, EVENT_DTYPE)
        if len(self._chunks) > 1:
            self._chunks = [np.concatenate(self._chunks)]
        return self._chunks[0]

    def _advance_history(self, ev: np.ndarray, t_us: int) -> None:
        """Apply the events in ``[_run_t, t_us)`` to each pixel's last polarity."""
        if t_us <= self._run_t:
            return
        if self._run_last is not None and ev.size:
            i0, i1 = np.searchsorted(ev["t"], [self._run_t, t_us], side="left")
            if i1 > i0:
                part = ev[i0:i1]
                h, w = self.shape
                if int(part["x"].max()) >= w or int(part["y"].max()) >= h:
                    raise EventFormatError(f"{self._source}: an event lies outside the {w}x{h} frames")
                update_last_polarity(part["x"], part["y"], part["p"], w, self._run_last)
        self._run_t = t_us

    def _drop_before(self, t_us: int) -> None:
        """Forget buffered events before ``t_us`` (after they updated the event history)."""
        if not self._chunks:
            return
        ev = self._events()
        self._advance_history(ev, t_us)
        cut = int(np.searchsorted(ev["t"], t_us, side="left"))
        self._chunks = [ev[cut:]] if cut < ev.size else []
        self._buffered = ev.size - cut

    def _on_frame(self, cur: Frame) -> None:
        if self.shape is None:
            self.shape = cur.shape
            self._run_last = np.zeros(cur.shape[0] * cur.shape[1], np.int8)
        elif cur.shape != self.shape:
            h, w = self.shape
            raise ParameterError(f"{self._source}: frames are {cur.shape[1]}x{cur.shape[0]}, earlier input "
                                 f"had {w}x{h}; calibrate one camera at a time")
        self.frames += 1
        ev = self._events()
        self._advance_history(ev, cur.exposure_start_us)
        entry = _Recent(cur, self.crf, self._run_last.copy() if self.continuation else None)
        if self._recent:
            last = self._recent[-1].frame
            if cur.exposure_start_us <= last.exposure_start_us or cur.exposure_start_us - last.exposure_end_us > self.max_gap_us:
                self.rejected["gap_or_order"] += 1
                self._close_group()
                self._recent = []
                self._group = []
            else:
                self._brackets(self._recent[-1], entry, ev)
                self.considered += 1
                self._pair(entry, ev)
        else:
            self._group = []
        self._recent.append(entry)
        if len(self._recent) > self.max_lag:
            self._recent.pop(0)
        self._drop_before(self._recent[0].frame.exposure_start_us)

    def _pair(self, cur: _Recent, ev: np.ndarray) -> None:
        """The pair of ``cur`` with the nearest earlier frame that has enough usable pixels."""
        for k in range(1, len(self._recent) + 1):
            prev = self._recent[-k]
            if cur.frame.exposure_start_us - prev.frame.exposure_end_us > self.max_gap_us:
                break
            if prev.used:
                continue
            both = prev.valid & cur.valid
            diff = cur.log_lbar - prev.log_lbar
            use = both & (np.abs(diff) >= self.min_change) if self.min_change > 0 else both
            if self.continuation:
                use &= np.sign(diff).astype(np.int8) == prev.last_polarity
            if int(use.sum()) >= self.min_pixels:
                pr = prepare_pair(ev, prev.frame, cur.frame, self.crf, reference=self.reference,
                                  max_pixels=self.max_pixels, mask=use, source=self._source)
                if pr is not None:
                    i0, i1 = np.searchsorted(ev["t"], [prev.frame.exposure_start_us, cur.frame.exposure_end_us])
                    if i1 > i0:
                        tt = ev["t"][i0:i1]
                        pr.bus_peak_rate = float(np.bincount((tt - tt[0]) // 1000).max()) * 1e3
                    for e in self._recent:  # pairs never overlap: later pairs start at cur or after
                        e.used = True
                    self.lags[k] = self.lags.get(k, 0) + 1
                    self._keep(pr)
                    return
        self.rejected["too_few_pixels"] += 1

    def _keep(self, pr: CalibrationPair) -> None:
        q = self.qualifying
        self.qualifying += 1
        if q % self.stride:
            return
        self.pairs.append(pr)
        self._bytes += pr.nbytes
        while len(self.pairs) > self.max_pairs or (self._bytes > self.max_bytes and len(self.pairs) > 1):
            self.pairs = self.pairs[::2]
            self.stride *= 2
            self._bytes = sum(p.nbytes for p in self.pairs)

    def _brackets(self, prev: _Recent, cur: _Recent, ev: np.ndarray) -> None:
        """Extend the static group with ``cur``, or close it.

        Static: fewer than ``static_events`` events per pixel from ``prev``'s exposure start to the
        end of ``cur``'s, and ``cur`` agrees with every frame of the group it overlaps: among the
        pixels well exposed in both (digital values 30..230, at least 2 % of the image), at most 2 %
        differ by more than 0.15 ln units in ``ln Lbar`` (starting response). Comparing with the
        whole group, not only the previous frame, catches slow lighting drifts.
        """
        pf, cf = prev.frame, cur.frame
        h, w = cf.shape
        t = ev["t"]
        n = int(np.searchsorted(t, cf.exposure_end_us, side="left") - np.searchsorted(t, pf.exposure_start_us,
                                                                                      side="left"))
        if not self._group:
            self._group = [(pf.image, pf.exposure_us * pf.gain, prev.log_lbar, _well(pf))]
        well = _well(cf)
        static = n / (h * w) <= self.static_events
        if static:
            for _, _, lg, wl in self._group:
                both = wl & well
                if both.sum() >= 0.02 * both.size:
                    if float(np.mean(np.abs(cur.log_lbar[both] - lg[both]) > 0.15)) > 0.02:
                        static = False
                        break
        if static:
            prod = cf.exposure_us * cf.gain
            if all(abs(math.log(prod / g[1])) > 0.05 for g in self._group) and len(self._group) < 32:
                self._group.append((cf.image, prod, cur.log_lbar, well))
        else:
            self._close_group()
            self._group = [(cf.image, cf.exposure_us * cf.gain, cur.log_lbar, well)]

    def _close_group(self) -> None:
        g = [(im, p) for im, p, *_ in self._group]
        self._group = []
        if len(g) < 3:
            return
        prods = [p for _, p in g]
        span = max(prods) / min(prods)
        if span < 4.0:
            return
        best = self.best_brackets
        if best is None or (len(g), span) > (len(best), max(p for _, p in best) / min(p for _, p in best)):
            self.best_brackets = list(g)

    def describe(self) -> dict:
        return {"sources": list(self.sources), "frames": self.frames, "events": int(self.events),
                "pairs_considered": self.considered, "pairs_qualifying": self.qualifying,
                "pairs_used": len(self.pairs), "thinning_stride": self.stride, "rejected": dict(self.rejected),
                "pairs_by_lag": {str(k): v for k, v in sorted(self.lags.items())},
                "selection": {"reference": self.reference, "min_change_ln": self.min_change,
                              "min_pixels": self.min_pixels, "max_pixels": self.max_pixels,
                              "max_pairs": self.max_pairs, "max_gap_us": self.max_gap_us, "max_lag": self.max_lag,
                              "continuation_rule": self.continuation},
                "bracket_frames": 0 if self.best_brackets is None else len(self.best_brackets)}


# ---------------------------------------------------------------------------------------------------
# simulator runs
# ---------------------------------------------------------------------------------------------------

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
            total = min(max(total * math.exp(BRACKET_OFFSETS[k % len(BRACKET_OFFSETS)]), aps.exposure_min_us),
                        aps.exposure_max_us * aps.gain_max)
        gain = max(1.0, total / aps.exposure_max_us)
        return total / gain, gain


def simulate_calibration_stream(scene, *, dvs=None, aps=None, crf: CameraResponse | None = None, seed: int = 0,
                                brackets: bool = True):
    """Packets (events, markers, frames) of one simulated camera driven by :class:`ExposureOracle`.

    The command for each frame is issued at the previous exposure start (the simulator's latency
    is far shorter than a frame interval), so every frame gets the oracle's exposure.
    """
    from .drivers.sim.aps import ApsParams
    from .drivers.sim.camera import SimRig

    aps = aps or ApsParams()
    crf = crf or default_davis346()
    oracle = ExposureOracle(scene, crf, aps, brackets)
    first = 1_000
    t0, k0 = oracle(first, 0)
    rig = SimRig(scene, {"cal": (t0, k0)}, dvs=dvs, aps=aps, crf=crf, seed=seed, first_start_us=first)
    k = 0
    for _, packet in rig.packets():
        if isinstance(packet, ExposureMarker) and packet.kind == "start":
            k += 1
            exp_us, gain = oracle(packet.t_us + aps.frame_interval_us, k)
            rig.set_exposure("cal", exp_us, gain)
        yield packet


def make_sim_scene(name: str, sensor: SensorGeometry, duration_s: float | None, seed: int):
    """The calibration scene (``"calibration"``) or an evaluation preset by name."""
    from .drivers.sim.calibration_scene import CALIBRATION_SCENE, CalibrationScene

    dur = None if duration_s is None else int(round(duration_s * 1e6))
    if name == CALIBRATION_SCENE:
        return CalibrationScene(sensor=sensor, duration_us=dur, seed=seed)
    from .drivers.sim.scenes import make_scenario

    return make_scenario(name, sensor=sensor, duration_us=dur, seed=seed)


# ---------------------------------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------------------------------


@dataclass
class CalibrationResult:
    """What a calibration produced and from what.

    ``profile``: the fitted camera profile (``params`` are its TEDI parameters); ``stderr``: the
    standard error of each fitted parameter (Gauss-Newton, independent residuals assumed; NaN when
    not fitted or at a bound, listed in ``at_bound``); ``rms_before``/``rms_after``: RMS Eq. 7
    residual (ln units) over all used pairs at ``init`` and at ``params``; ``plain``: thresholds
    only with ``a = b = 0`` fitted on all pairs (what the data give without compensation; ``None``
    when no compensation term was fitted); ``method``/``stages``: how the fit ran;
    ``crf_fitted``/``crf_info``: the response; ``data``: inputs and selection; ``pairs``: per-pair
    statistics with their RMS residual before and after; ``groups``: RMS before/after for the
    unsaturated and the saturated pairs (see :func:`calibrate_collected`).
    """

    profile: CameraProfile
    params: TediParams
    init: TediParams
    stderr: dict
    at_bound: list
    rms_before: float
    rms_after: float
    num_residuals: int
    plain: TediCalibration | None
    method: str
    stages: list
    crf_fitted: bool
    crf_info: dict
    data: dict
    pairs: list = field(default_factory=list)
    groups: dict = field(default_factory=dict)
    inactive: tuple = ()

    @property
    def inactive_names(self) -> tuple:
        return tuple(f"{k}_{pol}" for pol in self.inactive for k in ("a", "b"))

    def to_dict(self) -> dict:
        return {
            "profile": self.profile.to_dict(),
            "init": _params_dict(self.init),
            "fit": {"params": _params_dict(self.params), "stderr": {k: _num(v) for k, v in self.stderr.items()},
                    "at_bound": list(self.at_bound), "rms_before": self.rms_before, "rms_after": self.rms_after,
                    "residuals": self.num_residuals, "method": self.method, "stages": self.stages,
                    "inactive_compensation": list(self.inactive),
                    "groups": self.groups},
            "plain": None if self.plain is None else {
                "params": _params_dict(self.plain.params), "rms_after": self.plain.rms_after},
            "crf": {"fitted": self.crf_fitted, **self.crf_info},
            "data": self.data,
            "pairs": self.pairs,
        }

    def summary(self) -> str:
        p, se = self.params, self.stderr
        d = self.data
        lines = [f"data: {d.get('frames', '?')} frames, {d.get('pairs_considered', '?')} pairs considered, "
                 f"{len(self.pairs)} used ({self.num_residuals:,} pixel residuals; "
                 f"{self.groups.get('saturated', {}).get('pairs', 0)} reached the sensor's bus ceiling)",
                 f"fit: {self.method}", "fitted TEDI parameters (± standard error):"]
        for name in PARAM_NAMES:
            unit = " ev/s" if name.startswith("b_") else ""
            v, s = getattr(p, name), se.get(name, math.nan)
            if name in self.inactive_names:
                extra = " (inactive: no pixel of the data changed faster than the knee)"
            elif name in self.at_bound and name.startswith("b_") and getattr(p, "a_" + name[2:]) > 0:
                extra = f" (knee b/a = {v / getattr(p, 'a_' + name[2:]):.4g} ev/s: at its lower bound)"
            elif name in self.at_bound:
                extra = " (at bound)"
            elif s == math.inf:
                extra = " (not determined by these data)"
            elif math.isnan(s):
                extra = " (not fitted)"
            else:
                extra = ""
            lines.append(f"  {name:6s} {v:10.4g}{unit}" + (f" ± {s:.2g}" if math.isfinite(s) else "") + extra)
        lines.append(f"RMS residual (ln units), all pairs: {self.rms_before:.4f} at the start -> {self.rms_after:.4f} fitted")
        for key in ("unsaturated", "saturated"):
            g = self.groups.get(key)
            if g and g["pairs"]:
                lines.append(f"  {key} pairs ({g['pairs']}): {g['rms_before']:.4f} -> {g['rms_after']:.4f}"
                             + (f" (without compensation: {g['rms_plain']:.4f})" if g.get("rms_plain") is not None else ""))
        if self.plain is not None:
            lines.append(f"  without compensation (c± only, a = b = 0, all pairs): {self.plain.rms_after:.4f} "
                         f"(c_on {self.plain.params.c_on:.4f}, c_off {self.plain.params.c_off:.4f})")
        if self.crf_fitted:
            lines.append(f"camera response: fitted (Debevec-Malik) from {self.crf_info['frames']} bracketed frames, "
                         f"max |change| {self.crf_info['max_abs_change_ln']:.3f} ln over the valid range")
        else:
            lines.append(f"camera response: {self.crf_info.get('reason', 'kept')}")
        return "\n".join(lines)


def _num(v):
    if v is None or math.isnan(v):
        return None
    return "inf" if math.isinf(v) else float(v)


def _params_dict(p: TediParams) -> dict:
    return {n: float(getattr(p, n)) for n in PARAM_NAMES}


# ---------------------------------------------------------------------------------------------------
# the fit
# ---------------------------------------------------------------------------------------------------


def _resolve_fit(fit) -> tuple[str, ...]:
    if isinstance(fit, str):
        if fit in FIT_CHOICES:
            return FIT_CHOICES[fit]
        fit = [f.strip() for f in fit.split(",") if f.strip()]
    fit = tuple(fit)
    bad = [f for f in fit if f not in PARAM_NAMES]
    if not fit or bad or len(set(fit)) != len(fit):
        raise ParameterError(f"--fit must be 'all', 'c' or distinct names among {', '.join(PARAM_NAMES)}; "
                             f"got {','.join(fit) or 'nothing'}")
    return fit


def _fit_crf(collector: PairCollector, base: CameraResponse, mode: str) -> tuple[CameraResponse, bool, dict]:
    if mode == "keep":
        return base, False, {"reason": "kept the starting response (--crf keep)"}
    group = collector.best_brackets
    if not group:
        return base, False, {"reason": "kept the starting response (no exposure brackets of a static scene found)"}
    images = np.stack([im for im, _ in group])
    products = np.array([p for _, p in group], dtype=np.float64)
    fitted = debevec_malik(images, products)
    crf = CameraResponse(fitted.g, base.valid_min, base.valid_max)
    z = np.arange(base.valid_min, base.valid_max + 1)
    change = float(np.max(np.abs(crf.g[z] - base.g[z])))
    # consistency of the bracket: per pixel, g(Z) - ln(T K) should agree across the frames
    lh = crf.g[images.astype(np.int64)] - np.log(products / 1e6)[:, None, None]
    ok = (images >= crf.valid_min) & (images <= crf.valid_max)
    cnt = ok.sum(axis=0)
    mean = np.where(cnt > 0, (lh * ok).sum(axis=0) / np.maximum(cnt, 1), 0.0)
    dev = (lh - mean)[ok & (cnt >= 2)[None]]
    rms = float(np.sqrt(np.mean(dev ** 2))) if dev.size else math.nan
    return crf, True, {"frames": len(group), "exposure_gain_us": [float(p) for p in sorted(products)],
                       "max_abs_change_ln": change, "bracket_rms_ln": _num(rms)}


def _report(progress, text: str) -> None:
    if progress is not None:
        progress(text)


def _rms(parts) -> float:
    parts = [r for r in parts if r.size]
    if not parts:
        return math.nan
    r = np.concatenate(parts)
    return float(np.sqrt(np.mean(r ** 2)))


def _stage(name: str, pairs, res: TediCalibration) -> dict:
    return {"stage": name, "pairs": len(pairs), "fitted": [k for k, v in res.stderr.items() if math.isfinite(v)]
            + list(res.at_bound), "rms_before": res.rms_before, "rms_after": res.rms_after,
            "evaluations": res.evaluations, "success": res.success, "message": res.message}


def calibrate_collected(collector: PairCollector, *, base: CameraProfile | None = None, init: TediParams | None = None,
                        fit="all", crf_mode: str = "auto", name: str | None = None, limits: CameraLimits | None = None,
                        max_event_rate: float | None = None, slow_rate: float = DEFAULT_SLOW_RATE,
                        loss: str = DEFAULT_LOSS, f_scale: float = DEFAULT_F_SCALE, extra: dict | None = None,
                        progress=None, max_nfev: int = 200) -> CalibrationResult:
    """Fit response (if brackets) and TEDI parameters on what ``collector`` kept; build the profile.

    **Saturated pairs.** ``max_event_rate`` (events/s) is the sensor's bus ceiling: a pair whose
    sensor-wide event rate reached 90 % of it in any 1 ms bin is *saturated* — the sensor dropped
    events there, so its counts are incomplete whatever the thresholds are (``None``: unknown, no
    pair counts as saturated).

    **Stages.** When thresholds and compensation are both fitted and at least 3 pairs are not
    saturated, the fit runs in two stages:

    1. ``c±`` (with ``a = b = 0``) on the unsaturated pairs, where the counts are complete;
    2. the compensation ``a±, b±`` with ``c±`` fixed, on all pairs (it is there to credit what the
       sensor missed, at its bus ceiling or in refractory/slow pixels).

    Fitting them jointly lets the saturated pairs inflate the thresholds instead (measured on the
    simulated DAVIS346: c± +25-45 %), since a larger ``c`` credits more change to every event,
    which the least-squares fit prefers to a compensation that acts only above its knee. Otherwise
    (only one kind fitted, or too few unsaturated pairs) the named parameters are fitted jointly on
    all pairs. When ``a±`` and ``b±`` of a polarity are both fitted, the knee ``b±/a±`` is bounded
    below by ``slow_rate`` events per pixel per second: with a knee of zero the compensation
    ``a m`` is a mere rescaling of ``c``.
    """
    base = base or CameraProfile()
    init = init or base.tedi
    fit = _resolve_fit(fit)
    if crf_mode not in ("auto", "keep"):
        raise ParameterError(f"--crf must be auto or keep, got {crf_mode!r}")
    if isinstance(slow_rate, bool) or not isinstance(slow_rate, (int, float)) or not (math.isfinite(slow_rate)
                                                                                     and slow_rate > 0):
        raise ParameterError(f"slow_rate must be a positive number of events per pixel per second, got {slow_rate!r}")
    if max_event_rate is not None and (isinstance(max_event_rate, bool) or not isinstance(max_event_rate, (int, float))
                                       or not (math.isfinite(max_event_rate) and max_event_rate > 0)):
        raise ParameterError(f"max_event_rate must be a positive number of events per second, got {max_event_rate!r}")
    if not collector.pairs:
        d = collector
        if d.frames < 2:
            raise ParameterError(f"calibration needs frames with their exposures: the input held {d.frames} frame(s) "
                                 f"(formats without stored exposure need --exposure-us)")
        raise ParameterError(
            f"no frame pair qualifies: {d.considered} frames tried against up to {d.max_lag} earlier ones, none with "
            f"{d.min_pixels} pixels valid in both, changed by >= {d.min_change:g} ln"
            + (" and continuing their last event's direction" if d.continuation else "")
            + "; record lighting changes or motion, or lower --min-change / --min-pixels")
    crf, crf_fitted, crf_info = _fit_crf(collector, base.crf, crf_mode)
    pairs = collector.pairs
    t_fit = time.perf_counter()
    last = [0.0]
    label = [""]

    def cb(n, rms):
        now = time.perf_counter()
        if now - last[0] > 0.5:
            last[0] = now
            _report(progress, f"fitting {label[0]}: evaluation {n}, RMS residual {rms:.4f} ln ({now - t_fit:.0f} s)")

    c_names = tuple(n for n in fit if n.startswith("c_"))
    comp_names = tuple(n for n in fit if not n.startswith("c_"))
    knee = slow_rate if any(f"a_{p}" in fit and f"b_{p}" in fit for p in ("on", "off")) else 0.0
    limit = None if max_event_rate is None else 0.9 * float(max_event_rate)
    saturated = [limit is not None and pr.bus_peak_rate >= limit for pr in pairs]
    complete = [pr for pr, sat in zip(pairs, saturated) if not sat]
    robust = f", loss {loss}" + (f" (f_scale {f_scale:g} ln)" if loss != "linear" else "")
    knee_text = f", knee b/a >= {knee:g} ev/s per pixel" if knee else ""
    if c_names and comp_names and len(complete) >= 3:
        label[0] = f"thresholds on {len(complete)} unsaturated pairs"
        s1 = fit_tedi_pairs(complete, crf, TediParams(init.c_on, init.c_off), c_names, cb, max_nfev=max_nfev,
                            loss=loss, f_scale=f_scale)
        start = TediParams(s1.params.c_on, s1.params.c_off, init.a_on, init.b_on, init.a_off, init.b_off)
        label[0] = f"compensation on {len(pairs)} pairs"
        res = fit_tedi_pairs(pairs, crf, start, comp_names, cb, max_nfev=max_nfev, knee_min=knee, loss=loss,
                             f_scale=f_scale)
        stages = [_stage(f"{', '.join(c_names)} (a = b = 0) on the unsaturated pairs", complete, s1),
                  _stage(f"{', '.join(comp_names)} (c fixed) on all pairs", pairs, res)]
        stderr = {k: (s1.stderr[k] if k in c_names else res.stderr[k]) for k in PARAM_NAMES}
        at_bound = list(s1.at_bound) + list(res.at_bound)
        method = (f"two stages: {', '.join(c_names)} on the {len(complete)} unsaturated pairs, then "
                  f"{', '.join(comp_names)} on all {len(pairs)} pairs{robust}{knee_text}")
    else:
        label[0] = f"{len(pairs)} pairs"
        res = fit_tedi_pairs(pairs, crf, init, fit, cb, max_nfev=max_nfev, knee_min=knee, loss=loss, f_scale=f_scale)
        stages = [_stage(", ".join(fit) + " on all pairs", pairs, res)]
        stderr, at_bound = dict(res.stderr), list(res.at_bound)
        method = f"{', '.join(fit)} jointly on all {len(pairs)} pairs{robust}{knee_text}"
        if c_names and comp_names:
            method += f" (only {len(complete)} unsaturated pairs: too few for two stages)"
    params = res.params
    plain = None
    if comp_names:
        label[0] = "thresholds without compensation"
        plain = fit_tedi_pairs(pairs, crf, TediParams(params.c_on, params.c_off), ("c_on", "c_off"), cb,
                               max_nfev=max_nfev, loss=loss, f_scale=f_scale)
    r_before = pair_residuals(pairs, crf, init)
    r_after = pair_residuals(pairs, crf, params)
    r_plain = pair_residuals(pairs, crf, plain.params) if plain is not None else None
    groups = {}
    for key, want in (("unsaturated", False), ("saturated", True)):
        idx = [i for i, v in enumerate(saturated) if v == want]
        groups[key] = {"pairs": len(idx), "rms_before": _num(_rms([r_before[i] for i in idx])),
                       "rms_after": _num(_rms([r_after[i] for i in idx])),
                       "rms_plain": None if r_plain is None else _num(_rms([r_plain[i] for i in idx]))}
    groups["max_event_rate"] = max_event_rate
    per_pair = []
    for pr, rb, ra, sat in zip(pairs, r_before, r_after, saturated):
        per_pair.append({**pr.stats(), "saturated": sat, "rms_before": float(np.sqrt(np.mean(rb ** 2))),
                         "rms_after": float(np.sqrt(np.mean(ra ** 2)))})
    rms_before, rms_after = _rms(r_before), _rms(r_after)
    num_res = int(sum(pr.n for pr in pairs))
    h, w = collector.shape
    sensor = base.sensor if (base.sensor.width, base.sensor.height) == (w, h) else SensorGeometry(w, h, f"{w}x{h}")
    data = {**collector.describe(), **(extra or {})}
    calib = {
        "method": "Eq. 7 frame-to-frame consistency, squared residuals, SciPy least squares (trf); " + method,
        "data": {k: data[k] for k in ("sources", "frames", "pairs_used", "pairs_considered") if k in data}
        | ({"simulation": extra["simulation"]} if extra and "simulation" in extra else {}),
        "selection": {**data["selection"], "slow_rate": slow_rate, "max_event_rate": max_event_rate},
        "fitted": list(fit), "init": _params_dict(init),
        "rms_before": rms_before, "rms_after": rms_after,
        "rms_without_compensation": None if plain is None else plain.rms_after,
        "pairs_saturated": int(sum(saturated)),
        "stderr": {k: _num(v) for k, v in stderr.items() if k in fit},
        "crf": "fitted (Debevec-Malik)" if crf_fitted else crf_info.get("reason", "kept"),
    }
    profile = CameraProfile(name=name or base.name, sensor=sensor, crf=crf, tedi=params,
                            limits=limits or base.limits, calibration=calib)
    return CalibrationResult(profile, params, init, stderr, at_bound, rms_before, rms_after, num_res, plain, method,
                             stages, crf_fitted, crf_info, data, per_pair, groups, tuple(res.inactive))


def _collector(base: CameraProfile, kw: dict) -> PairCollector:
    opts = {k: kw.pop(k) for k in list(kw) if k in ("reference", *DEFAULTS) and kw[k] is not None}
    return PairCollector(base.crf, **opts)


def calibrate_from_recordings(paths, *, profile: CameraProfile | None = None, init: TediParams | None = None,
                              fit="all", crf: str = "auto", exposure_us: float | None = None, name: str | None = None,
                              max_event_rate="auto", slow_rate: float = DEFAULT_SLOW_RATE, loss: str = DEFAULT_LOSS,
                              f_scale: float = DEFAULT_F_SCALE, progress=None, max_nfev: int = 200,
                              **selection) -> CalibrationResult:
    """Calibrate from recorded files (any format :func:`~necviz.drivers.replay.open_recording` reads).

    ``profile``: the starting profile (response, limits, initial parameters; default DAVIS346);
    ``max_event_rate``: the sensor's bus ceiling in events/s (``"auto"``: 12 Mev/s for DAVIS346 and
    DAVIS240 frames, else unknown; ``None``: unknown), see :func:`calibrate_collected`;
    ``init`` overrides its TEDI parameters as the start; ``fit`` = ``"all"`` (six), ``"c"`` or a
    list of names; ``crf`` = ``"auto"`` (Debevec-Malik when a static exposure bracket is found)
    or ``"keep"``; ``selection``: :class:`PairCollector` options (``min_change``, ``min_pixels``,
    ``max_pixels``, ``max_pairs``, ``max_bytes``, ``max_gap_us``, ``reference``...).
    ``progress(text)`` gets a status line now and then.
    """
    from .drivers.replay import open_recording

    base = profile or CameraProfile()
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise ParameterError("give at least one recording")
    col = _collector(base, dict(selection))
    unknown = set(selection) - {"reference", *DEFAULTS}
    if unknown:
        raise ParameterError(f"unknown selection option(s): {', '.join(sorted(unknown))}")
    for path in paths:
        rec = open_recording(path, exposure_us=exposure_us)
        col.begin(str(path))
        t_wall, last, t_first, t_now = time.perf_counter(), 0.0, None, 0
        try:
            for packet in rec:
                col.feed(packet)
                if isinstance(packet, Frame):
                    t_now = packet.exposure_end_us
                    t_first = t_now if t_first is None else t_first
                    now = time.perf_counter()
                    if now - last > 0.5:
                        last = now
                        _report(progress, f"reading {path.name}: {(t_now - t_first) / 1e6:.1f} s, {col.frames} frames, "
                                          f"{len(col.pairs)} pairs kept ({now - t_wall:.0f} s)")
        finally:
            rec.close()
    col.finish()
    if max_event_rate == "auto":
        max_event_rate = KNOWN_EVENT_RATES.get((col.shape[1], col.shape[0])) if col.shape else None
    return calibrate_collected(col, base=base, init=init, fit=fit, crf_mode=crf, name=name,
                               max_event_rate=max_event_rate, slow_rate=slow_rate, loss=loss, f_scale=f_scale,
                               progress=progress, max_nfev=max_nfev)


def calibrate_from_simulation(scenarios=("calibration",), seeds=(0,), duration_s: float | None = None, *,
                              sensor: SensorGeometry = DAVIS346, dvs=None, aps=None, sim_crf: CameraResponse | None = None,
                              profile: CameraProfile | None = None, init: TediParams | None = None, fit="all",
                              crf: str = "auto", name: str | None = None, max_event_rate="auto",
                              slow_rate: float = DEFAULT_SLOW_RATE, loss: str = DEFAULT_LOSS, f_scale: float = DEFAULT_F_SCALE, progress=None,
                              max_nfev: int = 200, **selection) -> CalibrationResult:
    """Calibrate from simulator runs: every scenario x seed, one camera driven by :class:`ExposureOracle`.

    ``scenarios``: ``"calibration"`` (the held-out calibration scene) and/or preset names;
    ``dvs``/``aps``/``sim_crf``: the simulated camera (defaults: the simulated DAVIS346). The
    profile's limits are the simulated camera's. Other arguments as
    :func:`calibrate_from_recordings`.
    """
    from .drivers.sim.aps import ApsParams
    from .drivers.sim.dvs import DvsParams

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
                    _report(progress, f"simulating {sc} seed {sd}: {packet.exposure_end_us / 1e6:.2f}/"
                                      f"{scene.duration_us / 1e6:g} s, {len(col.pairs)} pairs kept ({now - t_wall:.0f} s)")
    col.finish()
    limits = CameraLimits(float(aps.exposure_min_us), float(aps.exposure_max_us), float(aps.gain_max))
    sim = {"scenarios": scenarios, "seeds": [int(s) for s in seeds],
           "duration_s": [s.duration_us / 1e6 for _, _, s in scenes][0], "sensor": f"{sensor.width}x{sensor.height}",
           "dvs": dvs.as_dict(), "exposure": "oracle (the scene's mean ln L), brackets in the static opening"}
    return calibrate_collected(col, base=base, init=init, fit=fit, crf_mode=crf, name=name, limits=limits,
                               max_event_rate=dvs.max_event_rate if max_event_rate == "auto" else max_event_rate,
                               slow_rate=slow_rate, loss=loss, f_scale=f_scale,
                               extra={"simulation": sim},
                               progress=progress, max_nfev=max_nfev)


# ---------------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------------


def parse_seeds(text: str) -> list[int]:
    """``"3"`` -> [3]; ``"0..4"`` -> [0, 1, 2, 3, 4] (inclusive); ``"1,5,9"`` -> [1, 5, 9]."""
    s = str(text).strip()
    try:
        if ".." in s:
            a, b = s.split("..", 1)
            lo, hi = int(a), int(b)
            if hi < lo:
                raise ValueError
            out = list(range(lo, hi + 1))
        else:
            out = [int(v) for v in s.split(",") if v.strip() != ""]
    except ValueError:
        raise ParameterError(f"--seeds expects N, a..b or a,b,c (non-negative integers), got {text!r}") from None
    if not out or any(v < 0 for v in out) or len(out) > 1000:
        raise ParameterError(f"--seeds expects N, a..b or a,b,c (non-negative integers, at most 1000), got {text!r}")
    return out


def _parse_init(text: str, base: TediParams) -> TediParams:
    parts = [p.strip() for p in str(text).split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        c_on, c_off = float(parts[0]), float(parts[1])
    except ValueError:
        raise ParameterError(f"--init expects c_on,c_off (two numbers in ln units, e.g. 0.26,0.24), got {text!r}") from None
    return TediParams(c_on, c_off, base.a_on, base.b_on, base.a_off, base.b_off)


def _parse_sensor(text: str) -> SensorGeometry:
    if text.upper() == "DAVIS346":
        return DAVIS346
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ParameterError(f"--sensor expects WIDTHxHEIGHT (e.g. 346x260), got {text!r}") from None
    if not (8 <= w <= 2048 and 8 <= h <= 2048):
        raise ParameterError(f"--sensor {text}: width and height must lie in 8..2048")
    return SensorGeometry(w, h, f"{w}x{h}")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``necviz calibrate`` on an ``argparse`` subparsers object; returns the parser."""
    p = subparsers.add_parser(
        "calibrate", help="fit a camera profile (TEDI c±, a±, b± by Eq. 7; response from brackets) from recordings or the simulator",
        description="Fits the six TEDI parameters by frame-to-frame consistency (Eq. 7) on recordings (any "
                    "supported format) or simulator runs, and the camera response (Debevec-Malik) where the data hold "
                    "exposure brackets of a static scene; writes a camera profile (JSON) for --profile.")
    p.add_argument("files", nargs="*", metavar="FILE", help="recordings (necviz, AEDAT 4/3.1/2.0, ROS bag, HDF5, RPG text)")
    p.add_argument("--sim", metavar="SCENARIO[,..]", default=None,
                   help="calibrate on simulator runs instead: 'calibration' (the held-out calibration scene) "
                        "and/or presets")
    p.add_argument("--seeds", default="0", metavar="a..b", help="with --sim: seeds (N, a..b or a,b,c; default 0)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="with --sim: simulated seconds per run")
    p.add_argument("--sensor", default="DAVIS346", metavar="WxH", help="with --sim: sensor size (default DAVIS346)")
    p.add_argument("--out", required=True, metavar="PROFILE.json", help="the camera profile to write")
    p.add_argument("--force", action="store_true", help="replace --out / --json if they exist")
    p.add_argument("--json", metavar="REPORT.json", default=None,
                   help="also write a report: fitted values, standard errors, residuals, per-pair statistics")
    p.add_argument("--profile", metavar="FILE", default=None,
                   help="starting profile (response, limits, initial parameters; default: DAVIS346 defaults)")
    p.add_argument("--init", metavar="c_on,c_off", default=None,
                   help="initial contrast thresholds in ln units (default: the starting profile's, 0.26,0.24)")
    p.add_argument("--fit", default="all", metavar="WHICH",
                   help="parameters to fit: all (default), c (thresholds only) or names, e.g. c_on,c_off,a_on,b_on")
    p.add_argument("--crf", choices=("auto", "keep"), default="auto",
                   help="auto: fit the response when the data hold exposure brackets of a static scene (default)")
    p.add_argument("--exposure-us", type=float, default=None, help="exposure for formats that do not store it")
    p.add_argument("--min-change", type=float, default=DEFAULTS["min_change"], metavar="LN",
                   help=f"use pixels whose frame-measured change is at least this (ln units; default {DEFAULTS['min_change']})")
    p.add_argument("--min-pixels", type=int, default=DEFAULTS["min_pixels"], metavar="N",
                   help=f"use a frame pair when at least N pixels qualify (default {DEFAULTS['min_pixels']})")
    p.add_argument("--max-pixels", type=int, default=DEFAULTS["max_pixels"], metavar="N",
                   help=f"pixels per pair at most, an even subsample (default {DEFAULTS['max_pixels']})")
    p.add_argument("--max-pairs", type=int, default=DEFAULTS["max_pairs"], metavar="N",
                   help=f"pairs kept at most, spread evenly over the data (default {DEFAULTS['max_pairs']})")
    p.add_argument("--max-lag", type=int, default=DEFAULTS["max_lag"], metavar="K",
                   help=f"pair a frame with up to K frames back when consecutive frames changed too little "
                        f"(default {DEFAULTS['max_lag']}; 1 = consecutive frames only)")
    p.add_argument("--no-continuation", action="store_true",
                   help="also use pixels whose change reverses the direction of their previous event "
                        "(biases the thresholds up; for recordings with too few events)")
    p.add_argument("--max-event-rate", type=float, default=None, metavar="MEV_S",
                   help="the sensor's bus ceiling in Mev/s: pairs that reached 90 %% of it are left out of the "
                        "threshold fit (default: 12 for DAVIS346/DAVIS240 recordings, the simulator's own with "
                        "--sim; 0 = unknown)")
    p.add_argument("--slow-rate", type=float, default=DEFAULT_SLOW_RATE, metavar="EV_S",
                   help=f"lower bound of the compensation knee b/a, events per pixel per second (default "
                        f"{DEFAULT_SLOW_RATE:g})")
    p.add_argument("--loss", choices=("linear", "soft_l1", "huber", "cauchy"), default=DEFAULT_LOSS,
                   help=f"least-squares loss (default {DEFAULT_LOSS}: squared residuals)")
    p.add_argument("--name", default=None, help="profile name (default: derived from the inputs)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from .outputs import check_distinct, check_output, write_json

    files = list(args.files or [])
    if files and args.sim:
        raise ParameterError("give recordings (FILE...) or --sim, not both")
    if not files and not args.sim:
        raise ParameterError("nothing to calibrate on: give recordings (FILE...) or --sim SCENARIO")
    inputs = files + ([args.profile] if args.profile else [])
    out = check_output(args.out, "--out", inputs=inputs, force=args.force, suffixes=(".json",))
    rep = None
    if args.json:
        rep = check_output(args.json, "--json", inputs=inputs, force=args.force, suffixes=(".json",))
        check_distinct({"--out": args.out, "--json": args.json})
    for f in files:
        if not Path(f).exists():
            raise ParameterError(f"{f}: no such file or directory")
    base = load_profile(args.profile) if args.profile else None
    fit = _resolve_fit(args.fit)
    init = _parse_init(args.init, (base or CameraProfile()).tedi) if args.init else None
    sel = {"min_change": args.min_change, "min_pixels": args.min_pixels, "max_pixels": args.max_pixels,
           "max_pairs": args.max_pairs, "max_lag": args.max_lag, "continuation": not args.no_continuation,
           "slow_rate": args.slow_rate, "loss": args.loss}
    if args.max_event_rate is not None:
        if not (math.isfinite(args.max_event_rate) and args.max_event_rate >= 0):
            raise ParameterError(f"--max-event-rate must be a number of Mev/s >= 0, got {args.max_event_rate}")
        rate = args.max_event_rate * 1e6 or None
    else:
        rate = "auto"
    live = sys.stderr.isatty()

    def progress(text):
        if live:
            print("\r  " + text[:100].ljust(100), end="", file=sys.stderr, flush=True)

    try:
        if files:
            name = args.name or f"calibrated from {', '.join(Path(f).name for f in files)}"[:120]
            result = calibrate_from_recordings(files, profile=base, init=init, fit=fit, crf=args.crf,
                                               exposure_us=args.exposure_us, name=name, max_event_rate=rate,
                                               progress=progress, **sel)
        else:
            from .drivers.sim.calibration_scene import CALIBRATION_SCENE
            from .drivers.sim.scenes import SCENARIOS

            scen = [s.strip() for s in args.sim.split(",") if s.strip()]
            bad = [s for s in scen if s != CALIBRATION_SCENE and s not in SCENARIOS]
            if not scen or bad:
                raise ParameterError(f"--sim: unknown scenario(s) {', '.join(bad) or '(none given)'}; available: "
                                     f"{CALIBRATION_SCENE}, {', '.join(sorted(SCENARIOS))}")
            seeds = parse_seeds(args.seeds)
            sensor = _parse_sensor(args.sensor)
            name = args.name or f"simulated {sensor.width}x{sensor.height} ({','.join(scen)}, seeds {args.seeds})"
            if base is not None and (base.sensor.width, base.sensor.height) != (sensor.width, sensor.height):
                base = CameraProfile(base.name, sensor, base.crf, base.tedi, base.limits)
            result = calibrate_from_simulation(scen, seeds, args.duration, sensor=sensor, profile=base, init=init,
                                               fit=fit, crf=args.crf, name=name, max_event_rate=rate,
                                               progress=progress, **sel)
    finally:
        if live:
            print("\r" + " " * 104 + "\r", end="", file=sys.stderr, flush=True)
    write_json(out, result.profile.to_dict(), indent=1)
    if rep is not None:
        write_json(rep, result.to_dict())
    print(result.summary())
    print(f"wrote {out}" + (f" and {rep}" if rep is not None else ""))
    return 0
