"""Choosing the frame pairs Eq. 7 is fitted on, from one stream of packets (recordings or simulator runs).

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

import math
from dataclasses import dataclass

import numpy as np

from necviz.calibration.settings import DEFAULTS
from necviz.core.crf import CameraResponse
from necviz.core.errors import EventFormatError, ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.tedi import CalibrationPair, PairSelection, prepare_pair
from necviz.core.tedi_kernels import update_last_polarity


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


#: The pixels a calibration pair uses unless told otherwise (:data:`~necviz.calibration.settings.DEFAULTS`):
#: at least 0.5 ln of change in at least 200 pixels, at most 5000 of them kept (module docstring).
DEFAULT_SELECTION = PairSelection(
    min_change=DEFAULTS["min_change"], min_pixels=DEFAULTS["min_pixels"], max_pixels=DEFAULTS["max_pixels"]
)


@dataclass(frozen=True)
class CollectorOptions:
    """How many pairs a :class:`PairCollector` keeps, how far apart their frames may be and how much it
    holds (validated here, once; which pixels a pair uses is its :class:`~necviz.core.tedi.PairSelection`).

    Parameters
    ----------
    max_pairs : int
        Pairs kept at most (>= 2); beyond it every other pair is dropped and from then on only every
        second qualifying pair is kept (module docstring).
    max_bytes : int
        The kept pairs' memory at most (bytes, >= 1), thinned the same way.
    max_gap_us : int
        Frames further apart than this (µs, >= 1; end of one to start of the next) never pair.
    max_lag : int
        A frame pairs with up to this many earlier frames (1..50; 1: Eq. 7's consecutive pairs).
    static_events : float
        Events per pixel (>= 0) below which two frames count as one static scene (exposure brackets).
    continuation : bool
        Use only pixels whose change continues the direction of their last event (module docstring).
    max_buffer_events : int
        Events buffered at most (>= 1) while waiting for a frame; beyond it the frames so far are
        dropped and pairing starts over.

    Raises
    ------
    ParameterError
        A count that is not an integer in its range, or a negative or non-finite ``static_events``.
    """

    max_pairs: int = DEFAULTS["max_pairs"]
    max_bytes: int = DEFAULTS["max_bytes"]
    max_gap_us: int = DEFAULTS["max_gap_us"]
    max_lag: int = DEFAULTS["max_lag"]
    static_events: float = DEFAULTS["static_events"]
    continuation: bool = DEFAULTS["continuation"]
    max_buffer_events: int = 30_000_000

    def __post_init__(self) -> None:
        for name, lo in (
            ("max_pairs", 2),
            ("max_bytes", 1),
            ("max_gap_us", 1),
            ("max_lag", 1),
            ("max_buffer_events", 1),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.max_lag > 50:
            raise ParameterError(f"max_lag must be at most 50 frames, got {self.max_lag}")
        v = self.static_events
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
            raise ParameterError(f"static_events must be a number >= 0, got {v!r}")
        object.__setattr__(self, "static_events", float(v))
        object.__setattr__(self, "continuation", bool(self.continuation))


class PairCollector:
    """Consume packets in stream order (event batches, exposure markers, frames) and keep the frame
    pairs Eq. 7 will use, plus the best static exposure-bracket group (module docstring).

    Call :meth:`begin` before each recording or run (forgets earlier frames), :meth:`feed` for
    every packet, :meth:`finish` at the end. Counters (``frames``, ``considered``, ``rejected``
    by reason, ``qualifying``, ``stride``, ``lags``) describe what happened.

    Pairing: for each new frame ``i`` the earlier frames ``i-1, i-2, ... i-max_lag`` are tried in
    that order and the first with at least ``selection.min_pixels`` usable pixels forms the pair; pairs never
    overlap (the earlier frame of a pair is never older than the later frame of the previous one),
    so a change is not counted again from every frame of the hold that follows it.
    ``max_lag = 1`` is Eq. 7's consecutive pairs; a longer baseline lets slow changes accumulate
    several events per pixel, which the thresholds need (with about one event per pixel the
    least-squares thresholds come out low).

    Parameters
    ----------
    crf : CameraResponse
        The response used to select pixels (the fit may use a refined one).
    selection : PairSelection
        Which pixels of a pair are used: the reference time, the change and pixel counts
        (default :data:`DEFAULT_SELECTION`).
    options : CollectorOptions, optional
        How many pairs are kept and how much is held (default: ``CollectorOptions()``).

    Raises
    ------
    ParameterError
        ``selection`` or ``options`` of another type.
    """

    def __init__(
        self,
        crf: CameraResponse,
        selection: PairSelection = DEFAULT_SELECTION,
        options: CollectorOptions | None = None,
    ):
        options = CollectorOptions() if options is None else options
        if not isinstance(selection, PairSelection):
            raise ParameterError(f"selection must be a PairSelection, got {type(selection).__name__}")
        if not isinstance(options, CollectorOptions):
            raise ParameterError(f"options must be a CollectorOptions, got {type(options).__name__}")
        self.crf = crf
        self.selection = selection
        self.options = options
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
        match packet:
            case EventBatch(events=ev) if ev.size:
                self._on_events(ev)
            case ExposureMarker(kind="start") if not self._recent:
                self._drop_before(packet.t_us)
            case Frame():
                self._on_frame(packet)

    def _on_events(self, events: np.ndarray) -> None:
        if events.dtype != EVENT_DTYPE:
            return
        self._chunks.append(events)
        self._buffered += events.size
        self.events += events.size
        if self._buffered > self.options.max_buffer_events:  # frames too far apart: start over
            if self._recent:
                self.rejected["gap_or_order"] += 1
            self._recent = []
            self._close_group()
            self._drop_before(int(events["t"][-1]) + 1)

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
            raise ParameterError(
                f"{self._source}: frames are {cur.shape[1]}x{cur.shape[0]}, earlier input "
                f"had {w}x{h}; calibrate one camera at a time"
            )
        self.frames += 1
        ev = self._events()
        self._advance_history(ev, cur.exposure_start_us)
        entry = _Recent(cur, self.crf, self._run_last.copy() if self.options.continuation else None)
        if self._recent:
            last = self._recent[-1].frame
            if (
                cur.exposure_start_us <= last.exposure_start_us
                or cur.exposure_start_us - last.exposure_end_us > self.options.max_gap_us
            ):
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
        if len(self._recent) > self.options.max_lag:
            self._recent.pop(0)
        self._drop_before(self._recent[0].frame.exposure_start_us)

    def _pair(self, cur: _Recent, ev: np.ndarray) -> None:
        """The pair of ``cur`` with the nearest earlier frame that has enough usable pixels."""
        for k in range(1, len(self._recent) + 1):
            prev = self._recent[-k]
            if cur.frame.exposure_start_us - prev.frame.exposure_end_us > self.options.max_gap_us:
                break
            if prev.used:
                continue
            both = prev.valid & cur.valid
            diff = cur.log_lbar - prev.log_lbar
            min_change = self.selection.min_change
            use = both & (np.abs(diff) >= min_change) if min_change > 0 else both
            if self.options.continuation:
                use &= np.sign(diff).astype(np.int8) == prev.last_polarity
            if int(use.sum()) >= self.selection.min_pixels:
                pr = prepare_pair(
                    ev,
                    prev.frame,
                    cur.frame,
                    self.crf,
                    selection=self.selection,
                    mask=use,
                    source=self._source,
                )
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
        opts = self.options
        while len(self.pairs) > opts.max_pairs or (self._bytes > opts.max_bytes and len(self.pairs) > 1):
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
        n = int(
            np.searchsorted(t, cf.exposure_end_us, side="left") - np.searchsorted(t, pf.exposure_start_us, side="left")
        )
        if not self._group:
            self._group = [(pf.image, pf.exposure_us * pf.gain, prev.log_lbar, _well(pf))]
        well = _well(cf)
        static = n / (h * w) <= self.options.static_events
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
        return {
            "sources": list(self.sources),
            "frames": self.frames,
            "events": int(self.events),
            "pairs_considered": self.considered,
            "pairs_qualifying": self.qualifying,
            "pairs_used": len(self.pairs),
            "thinning_stride": self.stride,
            "rejected": dict(self.rejected),
            "pairs_by_lag": {str(k): v for k, v in sorted(self.lags.items())},
            "selection": {
                "reference": self.selection.reference,
                "min_change_ln": float(self.selection.min_change),
                "min_pixels": int(self.selection.min_pixels),
                "max_pixels": None if self.selection.max_pixels is None else int(self.selection.max_pixels),
                "max_pairs": self.options.max_pairs,
                "max_gap_us": self.options.max_gap_us,
                "max_lag": self.options.max_lag,
                "continuation_rule": self.options.continuation,
            },
            "bracket_frames": 0 if self.best_brackets is None else len(self.best_brackets),
        }
