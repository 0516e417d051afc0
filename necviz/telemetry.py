"""Per-lane telemetry: what each camera's frames showed and what its controller did, in bounded memory.

The pipeline (:mod:`necviz.pipeline`) only runs the control loop; it hands every frame, exposure
start and command to a :class:`Telemetry`, which computes the per-frame metrics once
(:class:`FrameRecord`: over/under-exposed rates, the frame-measured and the predicted irradiance,
the prediction error, optionally SIFT inliers on raw and brightness-normalised frames; on
simulated frames the ground-truth metrics of :mod:`necviz.core.metrics`; on every saturated frame
its diagnosed cause, :mod:`necviz.core.diagnosis`; optionally the fiducial-marker detection scored
against the simulator's ground truth, :mod:`necviz.marker_detection`) for everyone who reads them: the Rerun sink,
the JSON summaries of ``replay``, and ``compare``.

The diagnosis needs to know the lanes (which controller, whether it drives its camera, the
commands it issues) and the source (command latency, limits): :meth:`Telemetry.attach` binds
them; without it the causes that need them are not named (a saturated frame still gets one).

Memory does not grow with the length of a run unless asked to:

* per-frame records live in a :class:`FrameTable` (columns of NumPy arrays); with
  ``history=N`` only the last ``N`` frames are kept (a live session), with ``history=None``
  every frame is kept (a comparison or a replay, bounded by its input);
* command latencies go into a :class:`LatencyHistogram` of fixed size (log-spaced bins, 1 %
  wide), from which percentiles are read;
* running totals (frames, saturated frames at 50 % and 10 %, commands, saturation causes, sums of
  the ground-truth metrics) count everything;
* the diagnosis keeps the lane's last :data:`COMMAND_HISTORY` commands and the pending exposure
  starts (at most a few).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from necviz.core.diagnosis import CAUSES, Command, Evidence, diagnose
from necviz.core.errors import NecvizError
from necviz.core.frames import Frame
from necviz.core.ground_truth import WELL_EXPOSED, GroundTruth, true_valid_fraction
from necviz.core.metrics import (
    exposure_rates_from_histogram,
    over_exposed_rate,
    rank_correlation,
    region_valid_fraction,
    under_exposed_rate,
)
from necviz.core.prediction_skill import SkillTracker
from necviz.image_quality import SiftMatcher
from necviz.marker_detection import MarkerDetector

if TYPE_CHECKING:
    from necviz.core.ptedi import PeripheralEstimator

#: A frame with more than this fraction of pixels clipped (either end) is *saturated* (the paper's
#: threshold); more than :data:`SLIGHTLY` is *slightly saturated*.
SATURATED = 0.5
SLIGHTLY = 0.1
#: Commands of each lane kept for the diagnosis (a few frames' worth even for NEC, which commands per event
#: batch): the controller-lag rule looks back from the change to the first frame that showed it.
COMMAND_HISTORY = 256
#: Exposure starts of anchoring frames whose count of events lost at the bus ceiling is kept (ground
#: truth), so the diagnosis knows how many were lost since P-TEDI's anchor.
ANCHOR_HISTORY = 64


@dataclass(slots=True)
class FrameRecord:
    """What one frame of one lane showed. Irradiances in ln units; NaN where not measurable.

    ``measured_log_irradiance`` is the frame's ln P̄ (frames with enough valid pixels);
    ``predicted_log_irradiance`` is P-TEDI's prediction for that exposure from the events before
    it (ln P(s) + ln E_p(s)); ``prediction_error`` their difference; ``persistence_error`` and
    ``trend_error`` the errors of two predictors that see frames only (the last usable frame's ln P̄;
    the line through the last two), ``prediction_skill`` P-TEDI's skill score against persistence
    over the lane's frames so far (:mod:`necviz.core.prediction_skill`). ``sift_inliers`` /
    ``sift_inliers_normalised``: SIFT inliers with the previous frame, raw and with both frames
    scaled to mean 128 DN. Ground truth (simulated frames): ``true_valid_fraction`` (pixels whose
    true irradiance was recorded inside 10..249 DN), ``rank_correlation`` (Spearman's ρ of the
    digits against the true irradiance on valid pixels), ``pedestrian_valid_fraction`` (on the
    first frame the scene's pedestrian is visible only). Fiducial markers (simulated frames, when
    the telemetry detects them; :mod:`necviz.core.markers`): ``marker_visible_mask`` /
    ``marker_detected_mask`` (bit ``1 << id`` per marker visible in the ground truth / found by the
    detector), ``marker_detection_rate`` (detected visible / visible) and ``marker_corner_error_px``
    (mean corner error of the detected visible markers). ``saturation_cause`` and
    ``saturation_explanation``: why a saturated frame saturated (``''`` otherwise).
    """

    sequence: int
    exposure_start_us: int
    exposure_end_us: int
    exposure_us: float
    gain: float
    over_exposed_rate: float
    under_exposed_rate: float
    measured_log_irradiance: float = math.nan
    predicted_log_irradiance: float = math.nan
    prediction_error: float = math.nan
    persistence_error: float = math.nan
    trend_error: float = math.nan
    prediction_skill: float = math.nan
    sift_inliers: float = math.nan
    sift_inliers_normalised: float = math.nan
    true_valid_fraction: float = math.nan
    rank_correlation: float = math.nan
    pedestrian_valid_fraction: float = math.nan
    marker_visible_mask: int = 0
    marker_detected_mask: int = 0
    marker_detection_rate: float = math.nan
    marker_corner_error_px: float = math.nan
    saturation_cause: str = ""
    saturation_explanation: str = ""

    @property
    def saturated(self) -> bool:
        return max(self.over_exposed_rate, self.under_exposed_rate) > SATURATED

    def as_dict(self) -> dict:
        """JSON-ready: NaN becomes ``None``; ``saturated`` included."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        for k, v in d.items():
            if isinstance(v, float) and not math.isfinite(v):
                d[k] = None
        d["saturated"] = self.saturated
        return d


_FIELDS = [f.name for f in fields(FrameRecord)]
_DTYPES = {
    f.name: (np.int64 if f.type in ("int", int) else object if f.type in ("str", str) else np.float64)
    for f in fields(FrameRecord)
}


class FrameTable:
    """Per-frame records as columns; keeps every frame, or the last ``capacity`` (a ring)."""

    def __init__(self, capacity: int | None = None):
        if capacity is not None and (not isinstance(capacity, int) or capacity < 1):
            raise NecvizError(f"frame history must be a positive integer or None, got {capacity!r}")
        self.capacity = capacity
        size = capacity if capacity is not None else 256
        self._cols = {k: np.empty(size, _DTYPES[k]) for k in _FIELDS}
        self._n = 0  # records ever appended
        self._len = 0

    def __len__(self) -> int:
        return self._len

    @property
    def total(self) -> int:
        """Records ever appended (more than ``len`` once a ring has wrapped)."""
        return self._n

    @property
    def nbytes(self) -> int:
        return sum(c.nbytes for c in self._cols.values())

    def add_row(self, rec: FrameRecord) -> None:
        """Keep ``rec`` (a ring drops its oldest row when full)."""
        values = [getattr(rec, k) for k in _FIELDS]  # not dataclasses.astuple: it deep-copies every field
        if self.capacity is None:
            i = self._n
            if i == len(self._cols[_FIELDS[0]]):
                self._cols = {k: np.concatenate([c, np.empty_like(c)]) for k, c in self._cols.items()}
            self._len += 1
        else:
            i = self._n % self.capacity
            self._len = min(self._len + 1, self.capacity)
        for k, v in zip(_FIELDS, values, strict=True):
            self._cols[k][i] = v
        self._n += 1

    def column(self, name: str) -> np.ndarray:
        """One field over the kept frames, oldest first (a copy)."""
        c = self._cols[name]
        if self.capacity is None or self._n <= self.capacity:
            return c[: self._len].copy()
        start = self._n % self.capacity
        return np.concatenate([c[start:], c[:start]])

    def rows(self) -> list[dict]:
        cols = {k: self.column(k) for k in _FIELDS}
        out = []
        for i in range(self._len):
            rec = FrameRecord(*(v if isinstance(v := cols[k][i], str) else v.item() for k in _FIELDS))
            out.append(rec.as_dict())
        return out


class LatencyHistogram:
    """Latencies in log-spaced bins 1 % wide from 0.1 µs to 100 s: fixed memory, percentiles to ~1 %."""

    LO_US = 0.1
    HI_US = 1e8
    STEP = math.log(1.01)

    def __init__(self):
        self.bins = np.zeros(int(math.ceil(math.log(self.HI_US / self.LO_US) / self.STEP)) + 2, np.int64)
        self.count = 0
        self.max_us = math.nan
        self.sum_us = 0.0

    def add(self, latency_us: float) -> None:
        v = max(latency_us, self.LO_US)
        k = min(int(math.log(v / self.LO_US) / self.STEP) + 1, len(self.bins) - 1)
        self.bins[k] += 1
        self.count += 1
        self.sum_us += latency_us
        if not latency_us <= self.max_us:
            self.max_us = latency_us

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile in µs (the geometric centre of its bin); NaN when empty."""
        if self.count == 0:
            return math.nan
        rank = q / 100.0 * self.count
        k = int(np.searchsorted(np.cumsum(self.bins), max(rank, 1), side="left"))
        if k == 0:
            return self.LO_US
        return min(self.LO_US * math.exp((k - 0.5) * self.STEP), self.max_us)


def _zone_mean(values, sizes=None) -> float:
    """Mean of per-zone values over the finite zones (weighted by zone sizes when given)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 1:
        return float(v[0])
    ok = np.isfinite(v)
    if not ok.any():
        return math.nan
    if sizes is None:
        return float(v[ok].mean())
    w = np.asarray(sizes, dtype=np.float64).ravel()[ok]
    return float((v[ok] * w).sum() / w.sum())


def _anchor_level(estimator: PeripheralEstimator) -> float:
    """P-TEDI's current anchor ln P(anchor) (mean over anchored zones); NaN if never anchored."""
    return _zone_mean(estimator.anchor_log, estimator.sizes)


def _anchor_time(estimator: PeripheralEstimator) -> int | None:
    """The oldest anchor time over the anchored zones (µs), ``None`` if never anchored."""
    if estimator.num_zones == 1:  # every exposure start: no array round trip for the whole sensor
        return int(estimator.anchor_t.item(0)) if math.isfinite(estimator.anchor_log.item(0)) else None
    ok = np.isfinite(estimator.anchor_log)
    return int(np.min(estimator.anchor_t[ok])) if ok.any() else None


class LaneTelemetry:
    """Telemetry of one lane (a camera and its controller).

    ``truth``: compute the ground-truth metrics of frames that carry truth (simulated frames;
    about 1 ms a frame); the diagnosis of saturated frames always runs. ``markers``: detect the
    scene's fiducial markers on frames whose truth has them (about 2 ms a frame).
    """

    def __init__(
        self, name: str, history: int | None = None, sift: bool = False, truth: bool = True, markers: bool = False
    ):
        self.name = name
        self.table = FrameTable(history)
        self.latency = LatencyHistogram()
        self.sift = SiftMatcher() if sift else None
        self.sift_normalised = SiftMatcher(normalise=True) if sift else None
        self.truth = bool(truth)
        self.markers = MarkerDetector() if markers else None
        self.skill = SkillTracker()  # P-TEDI against predictors that see frames only
        self._marker_counts = [0, 0]  # visible markers, detected visible markers (over every frame)
        self.frames = 0
        self.saturated_50 = 0
        self.saturated_10 = 0
        self.commands = 0
        self.causes: dict[str, int] = dict.fromkeys(CAUSES, 0)
        self._truth_sums = {"true_valid_fraction": [0.0, 0], "rank_correlation": [0.0, 0]}
        self.pedestrian: dict | None = None  # the first frame the scene's pedestrian is visible on
        self._predicted_at_start: dict[int, tuple[float, float, int | None]] = {}
        self._lost_at_anchor: dict[int, tuple[int, int]] = {}  # anchoring exposure start -> events lost so far
        self._commands: deque = deque(maxlen=COMMAND_HISTORY)
        self._lane = None  # the pipeline lane (controller, drives), bound by Telemetry.attach
        self._latency_us: float | None = None
        self._camera_limits: tuple | None = None
        self._last_start: int | None = None
        self._period_us: float | None = None
        self._previous: tuple[float, float] | None = None  # (over, under) of the previous frame
        self._recent: deque = deque(maxlen=4)  # (start, end, exposure x gain) of the last frames
        # events the lane's controller had received by each exposure start, and since P-TEDI's anchor up to
        # this frame (the diagnosis: what it saw, not what it declares)
        self._delivered_at_start: dict[int, int] = {}
        self._received = 0
        self._zone_sizes = None  # pixels per P-TEDI zone (weights of zone means)

    def bind(self, lane=None, latency_us: float | None = None, limits=None) -> None:
        """Bind the pipeline lane (its controller and whether it drives the camera), the source's
        command latency (µs) and the camera's limits ``(exposure_min_us, exposure_max_us, gain_max)``."""
        self._lane = lane
        if latency_us is not None:
            self._latency_us = float(latency_us)
        if limits is not None:
            self._camera_limits = tuple(float(v) for v in limits)

    def exposure_start(self, t_us: int, estimator) -> None:
        """Remember P-TEDI's ln P(s) and its anchor at an exposure start (the frame's prediction error,
        the diagnosis' predicted change)."""
        self._delivered_at_start[int(t_us)] = self._events_delivered()
        while len(self._delivered_at_start) > ANCHOR_HISTORY:
            del self._delivered_at_start[next(iter(self._delivered_at_start))]
        if estimator is not None and estimator.ready:
            self._zone_sizes = estimator.sizes
            try:
                self._predicted_at_start[int(t_us)] = (
                    estimator.predict(t_us),
                    _anchor_level(estimator),
                    _anchor_time(estimator),
                )
            except NecvizError:
                pass

    def command(self, latency_us: float, command=None) -> None:
        """A command was issued and handed to the source after ``latency_us`` of processing. The
        command itself (an :class:`~necviz.core.control.ExposureCommand`) is kept for the diagnosis:
        ``command``, else the bound lane's ``controller.last_command`` (the pipeline reports a
        command right after the controller's ``feed`` returned it)."""
        self.commands += 1
        self.latency.add(latency_us)
        cmd = (
            command if command is not None else (self._lane.controller.last_command if self._lane is not None else None)
        )
        if cmd is not None:
            self._commands.append(Command(int(cmd.issue_time_us), float(cmd.exposure_us), float(cmd.gain)))

    def frame(self, frame: Frame, estimate, min_valid_fraction: float) -> FrameRecord:
        """The record of a frame, given what the lane's P-TEDI made of it (``estimate``, may be None)."""
        image = frame.image
        est = self._lane.estimator if self._lane is not None else None
        hist = est.counted_digit_histogram(frame) if est is not None else None
        if hist is not None:  # P-TEDI counted this frame's digits: the same rates without two passes
            over, under = exposure_rates_from_histogram(hist, image.size)
        else:
            over, under = over_exposed_rate(image), under_exposed_rate(image)
        rec = FrameRecord(
            int(frame.sequence),
            int(frame.exposure_start_us),
            int(frame.exposure_end_us),
            float(frame.exposure_us),
            float(frame.gain),
            over,
            under,
        )
        s = rec.exposure_start_us
        pred_s, anchor_s, anchor_t = self._predicted_at_start.pop(s, (math.nan, math.nan, None))
        since = self._delivered_at_start.get(anchor_t if anchor_t is not None else s, 0)
        self._received = self._events_delivered() - since
        for k in [k for k in self._predicted_at_start if k < s]:  # starts whose frame never came
            del self._predicted_at_start[k]
        if estimate is not None:
            lm = estimate.log_mean_irradiance
            one = lm.size == 1  # the whole sensor: floats, not one-element arrays
            measured = lm.item(0) if one else float(np.nanmean(lm))
            vf = estimate.valid_fraction
            valid = vf.item(0) >= min_valid_fraction if one else bool(np.all(vf >= min_valid_fraction))
            if math.isfinite(measured) and valid:
                rec.measured_log_irradiance = measured
                if math.isfinite(pred_s):
                    log_e = estimate.log_e.item(0) if one else float(np.mean(estimate.log_e))
                    rec.predicted_log_irradiance = pred_s + log_e  # ln P̄ = ln P(s) + ln E_p(s)
                    rec.prediction_error = rec.predicted_log_irradiance - measured
        rec.persistence_error, rec.trend_error, rec.prediction_skill = self.skill.update(
            rec.measured_log_irradiance, rec.prediction_error, (s + rec.exposure_end_us) / 2
        )
        if self.sift is not None:
            n = self.sift.next(image)
            rec.sift_inliers = math.nan if n is None else float(n)
            n = self.sift_normalised.next(image)
            rec.sift_inliers_normalised = math.nan if n is None else float(n)
        truth = frame.truth
        if truth is not None and self.truth:
            self._truth_metrics(rec, frame, truth)
        worst = max(over, under)
        if worst > SATURATED:
            lost = self._lost_change(truth, anchor_t, rec.exposure_end_us)
            rec.saturation_cause, rec.saturation_explanation = diagnose(
                self._evidence(rec, frame, estimate, pred_s, anchor_s, lost)
            )
            self.causes[rec.saturation_cause] = self.causes.get(rec.saturation_cause, 0) + 1
        if truth is not None and estimate is not None:
            moved = estimate.anchored.any() or (estimate.bounded is not None and estimate.bounded.any())
            at = truth.lost_at(s) if moved else None
            if at is not None:
                self._lost_at_anchor[s] = at
                while len(self._lost_at_anchor) > ANCHOR_HISTORY:
                    del self._lost_at_anchor[next(iter(self._lost_at_anchor))]
        if self._last_start is not None and s > self._last_start:
            self._period_us = float(s - self._last_start)
        self._last_start = s
        self._previous = (over, under)
        self._recent.append((s, rec.exposure_end_us, rec.exposure_us * rec.gain))
        self.frames += 1
        self.saturated_50 += worst > SATURATED
        self.saturated_10 += worst > SLIGHTLY
        self.table.add_row(rec)
        return rec

    def _truth_metrics(self, rec: FrameRecord, frame: Frame, truth: GroundTruth) -> None:
        rec.true_valid_fraction = true_valid_fraction(truth, frame.exposure_us, frame.gain)
        rec.rank_correlation = rank_correlation(frame.image, truth.mean_irradiance)
        for key in self._truth_sums:
            v = getattr(rec, key)
            if math.isfinite(v):
                self._truth_sums[key][0] += v
                self._truth_sums[key][1] += 1
        mk = truth.markers
        if self.markers is not None and mk is not None:
            vis, det, rate, err = self.markers.score(frame.image, mk)
            rec.marker_visible_mask, rec.marker_detected_mask = vis, det
            rec.marker_detection_rate, rec.marker_corner_error_px = rate, err
            n_vis = bin(vis).count("1")
            self._marker_counts[0] += n_vis
            self._marker_counts[1] += bin(vis & det).count("1")
        box = truth.pedestrian_box
        if self.pedestrian is None and box is not None:
            rec.pedestrian_valid_fraction = region_valid_fraction(frame.image, box)
            self.pedestrian = {
                "frame": rec.sequence,
                "valid_fraction": rec.pedestrian_valid_fraction,
                "well_exposed": bool(rec.pedestrian_valid_fraction >= WELL_EXPOSED),
                "box": [int(v) for v in box],
            }

    def _events_delivered(self) -> int:
        """Events the lane's controller has received so far: those its own estimator counted (0 for a
        controller that has none, or that is fed none, like ``nec-frames``)."""
        est = self._lane.controller.estimator if self._lane is not None else None
        if est is None:
            return 0
        on, off = est.event_totals()
        return int(on) + int(off)

    def _lost_change(self, truth, anchor_t: int | None, end_us: int) -> float:
        """The log change carried by the events lost at the bus ceiling between P-TEDI's anchor (at
        ``anchor_t``) and ``end_us`` (ground truth); NaN where unknown."""
        if truth is None or anchor_t is None:
            return math.nan
        then = self._lost_at_anchor.get(int(anchor_t)) or truth.lost_at(anchor_t)
        now = truth.lost_at(end_us)
        if then is None or now is None:
            return math.nan
        return truth.lost_log_change(now[0] - then[0], now[1] - then[1])

    def _evidence(
        self, rec: FrameRecord, frame: Frame, estimate, pred_s: float, anchor_s: float, lost: float = math.nan
    ) -> Evidence:
        """What is known about a saturated frame, for :func:`~necviz.core.diagnosis.diagnose`."""
        truth = frame.truth
        lane = self._lane
        ctrl = lane.controller if lane is not None else None
        mins, maxs, gains = [], [], []
        if ctrl is not None:
            lim = ctrl.limits
            mins.append(lim.exposure_min_us), maxs.append(lim.exposure_max_us), gains.append(lim.gain_max)
        cam = (
            (truth.exposure_min_us, truth.exposure_max_us, truth.gain_max) if truth is not None else self._camera_limits
        )
        if cam is not None:
            mins.append(cam[0]), maxs.append(cam[1]), gains.append(cam[2])
        latency = truth.latency_us if truth is not None else self._latency_us
        frame_change = exposure_change = math.nan
        if estimate is not None:
            exposure_change = _zone_mean(estimate.log_e, self._zone_sizes)
            if math.isfinite(anchor_s):
                frame_change = _zone_mean(estimate.log_anchor, self._zone_sizes) - anchor_s
        d = 1 if rec.over_exposed_rate >= rec.under_exposed_rate else -1
        prev = None
        if self._previous is not None:
            prev = (self._previous[0] if d > 0 else self._previous[1]) > SATURATED
        return Evidence(
            rec.sequence,
            rec.exposure_start_us,
            rec.exposure_end_us,
            rec.exposure_us,
            rec.gain,
            rec.over_exposed_rate,
            rec.under_exposed_rate,
            truth,
            max(mins) if mins else None,
            min(maxs) if maxs else None,
            min(gains) if gains else None,
            latency,
            None if ctrl is None else self._received > 0,
            None if lane is None else bool(lane.drives),
            tuple(self._commands),
            pred_s - anchor_s if math.isfinite(anchor_s) else math.nan,
            frame_change,
            exposure_change,
            self._period_us,
            prev,
            tuple(self._recent),
            lost,
        )

    def prediction_errors(self) -> np.ndarray:
        e = self.table.column("prediction_error")
        return e[np.isfinite(e)]

    def truth_summary(self) -> dict:
        """Means of the ground-truth metrics over every frame that had them, and the pedestrian's first frame."""
        out = {f"{k}_mean": (t / n if n else None) for k, (t, n) in self._truth_sums.items()}
        n_vis, n_hit = self._marker_counts
        out["marker_detection_rate"] = n_hit / n_vis if n_vis else None
        p = self.pedestrian
        out.update(
            {
                "pedestrian_frame": p["frame"] if p else None,
                "pedestrian_valid_fraction": p["valid_fraction"] if p else None,
                "pedestrian_well_exposed": p["well_exposed"] if p else None,
            }
        )
        return out

    def summary(self) -> dict:
        """Counts, latency percentiles, saturation causes and ground-truth means (JSON-ready)."""
        err = self.prediction_errors()
        return {
            "frames": self.frames,
            "saturated_frames_50": self.saturated_50,
            "saturated_frames_10": self.saturated_10,
            "commands": self.commands,
            "latency_p50_us": self.latency.percentile(50),
            "latency_p99_us": self.latency.percentile(99),
            "latency_max_us": self.latency.max_us,
            "prediction_error_rmse": float(np.sqrt(np.mean(err**2))) if err.size else None,
            "prediction_error_frames": int(err.size),
            "prediction_skill": self.skill.summary(),
            "saturation_causes": dict(self.causes),
            **self.truth_summary(),
        }


class Telemetry:
    """Telemetry of every lane of a run, plus stream totals.

    ``history``: frames kept per lane (``None``: all); ``sift``: compute SIFT inliers between
    consecutive frames of each lane, raw and brightness-normalised (about 80 ms a frame:
    comparisons only); ``truth``: compute the ground-truth metrics of simulated frames (about
    1 ms a frame and lane); ``markers``: detect the simulated scene's fiducial markers on every
    frame and score them against the ground truth (about 2 ms a frame and lane).
    """

    def __init__(
        self, lanes, history: int | None = None, sift: bool = False, truth: bool = True, markers: bool = False
    ):
        self.lanes = {name: LaneTelemetry(name, history, sift, truth, markers) for name in lanes}
        self.events = 0
        self.frames = 0
        self.first_us: int | None = None
        self.now_us: int | None = None

    def __getitem__(self, lane: str) -> LaneTelemetry:
        return self.lanes[lane]

    def attach(self, lanes, source=None) -> Telemetry:
        """Bind pipeline lanes (by name) and the source, for the diagnosis of saturated frames: each
        lane's controller (does it see events, its commands, its limits) and whether it drives its
        camera; the source's command latency and camera limits (its
        :class:`~necviz.drivers.source.CameraInfo`). Safe to call again."""
        info = source.camera_info if source is not None else None
        latency = info.command_latency_us if info is not None else None
        lim = info.limits if info is not None else None
        limits = None if lim is None else (lim.exposure_min_us, lim.exposure_max_us, lim.gain_max)
        for ln in lanes:
            if ln.name in self.lanes:
                self.lanes[ln.name].bind(ln, latency, limits)
        return self

    @property
    def duration_s(self) -> float:
        return ((self.now_us or 0) - (self.first_us or 0)) / 1e6

    def summary(self) -> dict:
        span = self.duration_s
        return {
            "events": self.events,
            "frames": self.frames,
            "duration_s": span,
            "event_rate_mev_s": self.events / span / 1e6 if span > 0 else 0.0,
            "lanes": {name: lane.summary() for name, lane in self.lanes.items()},
        }


__all__ = [
    "ANCHOR_HISTORY",
    "COMMAND_HISTORY",
    "FrameRecord",
    "FrameTable",
    "LaneTelemetry",
    "LatencyHistogram",
    "SATURATED",
    "SLIGHTLY",
    "Telemetry",
]
