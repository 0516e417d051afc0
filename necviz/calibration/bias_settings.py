"""Calibration per DVS bias setting: each setting's frames and events fitted on their own.

The biases set the contrast thresholds (:mod:`necviz.core.biases`), so a recording whose biases changed holds
data of several cameras as far as TEDI is concerned. :class:`BiasTimeline` says which setting held when: from a
native recording's notes (``dvs`` notes, each change's time of effect from the ``ptedi`` note that followed it, as
``necviz replay`` follows them) or from a simulator run's schedule (``--dvs-at``, the time of effect the simulator
reports). :class:`SplitCollector` routes the stream to one :class:`~.pairs.PairCollector` per setting: events split
at each change, a frame whose exposure spans a change dropped, and frames never paired across a change (each
collector starts over when the stream comes back to it). Setting 0 is the biases the stream started with; the
others are numbered in the order they first appear (a later return to the same settings is the same setting).

The time of effect is exact for the simulator and the emulated camera; for a real camera it is the time of the
last packet delivered when the biases were written (:mod:`necviz.dvs_controls`), so a pair straddling it by a
packet may be kept.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame

#: the recorded settings that tell two bias settings apart (``dvs`` notes, :meth:`DvsControls.set`)
SETTING_KEYS = ("c_on", "c_off", "refractory_us", "bandwidth_hz", "ba_filter_us", "refractory_filter_us")


def _key(settings: dict) -> tuple:
    return tuple(round(float(settings[k]), 6) if settings.get(k) is not None else None for k in SETTING_KEYS)


@dataclass
class BiasTimeline:
    """Which bias setting held when: ``changes`` are ``(from_us, setting index)`` in time order (setting 0 before
    the first); ``settings[i]`` describes setting ``i`` (``None`` for the biases the stream started with, when not
    recorded). Append-only: a simulated run adds its changes as they take effect."""

    settings: list = field(default_factory=lambda: [None])
    changes: list = field(default_factory=list)
    _keys: dict = field(default_factory=dict)

    def add(self, from_us: int, settings: dict) -> int:
        """The setting ``settings`` (a ``dvs`` note's values) holds from ``from_us``; returns its index."""
        k = _key(settings)
        if k not in self._keys:
            self._keys[k] = len(self.settings)
            self.settings.append({key: settings.get(key) for key in (*SETTING_KEYS, "truth") if key in settings})
        idx = self._keys[k]
        t = int(from_us)
        if self.changes and t < self.changes[-1][0]:
            raise ParameterError(f"bias changes out of time order ({t} us after {self.changes[-1][0]} us)")
        if self.changes and self.changes[-1][0] == t:
            self.changes[-1] = (t, idx)  # written together: one change
        elif (self.changes[-1][1] if self.changes else 0) != idx:
            self.changes.append((t, idx))
        return idx

    def restart(self) -> None:
        """A new run or recording: it starts at setting 0 again (the indices are kept)."""
        self.changes = []

    def at(self, t_us: int) -> int:
        """The setting that held at ``t_us``."""
        i = bisect.bisect_right([t for t, _ in self.changes], int(t_us)) - 1
        return 0 if i < 0 else self.changes[i][1]

    def boundaries(self) -> list[int]:
        return [t for t, _ in self.changes]

    @classmethod
    def from_annotations(cls, annotations, timeline: BiasTimeline | None = None) -> BiasTimeline:
        """A native recording's notes: each ``dvs`` change from the time its ``ptedi`` note says it showed in the
        stream (``from_us``), else from the time it was written (a change that moved no threshold has no
        ``ptedi`` note; one set before the first packet is noted at that packet)."""
        tl = cls() if timeline is None else timeline
        tl.restart()
        pending: tuple[int, dict] | None = None  # a threshold change written, waiting for the note that it showed
        for t, note in sorted(annotations or (), key=lambda a: a[0]):
            if not isinstance(note, dict):
                continue
            dvs, ptedi = note.get("dvs"), note.get("ptedi")
            starts = (
                [v["from_us"] for v in ptedi.values() if isinstance(v, dict) and "from_us" in v]
                if isinstance(ptedi, dict)
                else []
            )
            if starts:  # a change showed in the stream here (a replay's note carries the recorded settings)
                settings = dvs if isinstance(dvs, dict) else (pending[1] if pending else None)
                if settings is not None:
                    tl.add(int(starts[0]), settings)
                pending = None
            elif isinstance(dvs, dict):
                if isinstance(ptedi, dict):  # set before the stream started: P-TEDI took it at once
                    tl.add(int(t), dvs)
                elif pending is not None or dvs.get("ptedi") or "ratio" in dvs:
                    # thresholds moved (now or in a change not yet shown): the note that they showed says when;
                    # each note holds every setting after it, so the latest stands for both
                    pending = (pending[0] if pending else int(t), dvs)
                else:  # the refractory period or bandwidth alone: no such note comes, it holds from now
                    tl.add(int(t), dvs)
        if pending is not None:
            tl.add(*pending)
        return tl


class SplitCollector:
    """One :class:`~.pairs.PairCollector` per bias setting of ``timeline``, made by ``make()`` when first needed;
    :meth:`feed` routes each packet to the setting that held at its time."""

    def __init__(self, timeline: BiasTimeline, make):
        self.timeline = timeline
        self.make = make
        self.collectors: dict = {}
        self.frames_dropped = 0  # exposures that spanned a change
        self._source = ""
        self._active: int | None = None
        self._segment: int | None = None

    def begin(self, source: str) -> None:
        """A new recording or run (the timeline restarts at setting 0 unless the caller fills it first)."""
        self._source = source
        self._active = self._segment = None

    def _route(self, t_us: int):
        seg = bisect.bisect_right(self.timeline.boundaries(), int(t_us))
        idx = self.timeline.at(t_us)
        if seg != self._segment:  # a new stretch: its collector starts over (no pair across a change)
            col = self.collectors.get(idx)
            if col is None:
                col = self.collectors[idx] = self.make()
            col.begin(f"{self._source} (bias setting {idx})")
            self._segment, self._active = seg, idx
        return self.collectors[idx]

    def feed(self, packet) -> None:
        match packet:
            case EventBatch(events=ev) if ev.size:
                t = ev["t"]
                cuts = [c for c in self.timeline.boundaries() if int(t[0]) < c <= int(t[-1])]
                start = 0
                for c in [*cuts, None]:
                    end = len(t) if c is None else int(np.searchsorted(t, c, side="left"))
                    if end > start:
                        part = ev[start:end]
                        self._route(int(part["t"][0])).feed(EventBatch(part))
                    start = end
            case ExposureMarker():
                self._route(packet.t_us).feed(packet)
            case Frame():
                start, end = packet.exposure_start_us, packet.exposure_end_us
                if self.timeline.at(start) != self.timeline.at(end) or any(
                    start < c <= end for c in self.timeline.boundaries()
                ):
                    self.frames_dropped += 1  # the collector of the stretch after it has no frame yet: no pair
                    return
                self._route(start).feed(packet)

    def finish(self) -> None:
        for col in self.collectors.values():
            col.finish()


@dataclass
class SettingResult:
    """One bias setting's fit: its index, its settings (the recorded ones; a simulated run adds its pixel's true
    thresholds as ``truth``), the :class:`~.fit.CalibrationResult` or why there is none (``error``)."""

    index: int
    settings: dict | None
    result: object | None = None
    error: str | None = None

    def to_dict(self) -> dict:
        return {
            "bias_setting": self.index,
            "settings": self.settings,
            "error": self.error,
            "calibration": None if self.result is None else self.result.to_dict(),  # type: ignore[attr-defined]
        }


def fit_settings(split: SplitCollector, which, options, *, limits=None, extra=None, progress=None) -> list:
    """Fit each collected setting (``which == "all"``) or setting ``which``; the profile of each carries
    ``calibration.bias_setting`` (its index and settings). A setting without a qualifying frame pair is reported
    (``error``) under ``all`` and refused alone; refused too when no setting could be fitted."""
    from necviz.calibration.fit import calibrate_collected

    split.finish()
    n = len(split.timeline.settings)
    if which != "all" and not 0 <= int(which) < n:
        raise ParameterError(
            f"--bias-setting {which}: the data hold bias setting{'s 0..' + str(n - 1) if n > 1 else ' 0 only'}"
        )
    out = []
    for i in range(n) if which == "all" else [int(which)]:
        desc = split.timeline.settings[i]
        col = split.collectors.get(i)
        if col is None or not col.frames:
            res = SettingResult(i, desc, error="no frame at this bias setting")
        else:
            try:
                r = calibrate_collected(col, options, limits=limits, extra=extra, progress=progress)
            except ParameterError as e:
                res = SettingResult(i, desc, error=str(e))
            else:
                r.profile.calibration["bias_setting"] = {"index": i, "settings": desc}
                r.data["bias_setting"] = {
                    "index": i,
                    "settings": desc,
                    "frames_dropped_at_changes": split.frames_dropped,
                }
                res = SettingResult(i, desc, r)
        if res.error is not None and which != "all":
            raise ParameterError(f"--bias-setting {i}: {res.error}")
        out.append(res)
    if not any(r.result is not None for r in out):
        raise ParameterError("no bias setting could be fitted: " + "; ".join(f"{r.index}: {r.error}" for r in out))
    return out


def parse_setting(text) -> int | str:
    """``--bias-setting``: ``"all"`` or a setting number."""
    s = str(text).strip().lower()
    if s == "all":
        return "all"
    try:
        n = int(s)
    except ValueError:
        n = -1
    if n < 0:
        raise ParameterError(
            f"--bias-setting takes a setting number (0 = the biases the data start with) or all, got {text!r}"
        )
    return n


def parse_change(text) -> tuple[float, str, str]:
    """``--dvs-at SECONDS:KEY=VALUE`` -> ``(seconds, key, value)``, checked against the bias model; one-line error."""
    from necviz.dvs_controls import check_assignments

    at, sep, rest = str(text).partition(":")
    try:
        t = float(at)
    except ValueError:
        t = -1.0
    if not sep or not t >= 0 or t > 600:
        raise ParameterError(f"--dvs-at takes SECONDS:KEY=VALUE (e.g. 3:c_on=0.15, seconds in 0..600), got {text!r}")
    ((key, value),) = check_assignments([rest])
    if key.startswith("bias.") or key in ("ba_filter_us", "refractory_filter_us"):
        raise ParameterError(
            f"--dvs-at {text}: the simulator takes c_on, c_off, refractory_us and bandwidth_hz (no raw biases or FPGA filters)"
        )
    return t, key, value


__all__ = [
    "SETTING_KEYS",
    "BiasTimeline",
    "SettingResult",
    "SplitCollector",
    "fit_settings",
    "parse_change",
    "parse_setting",
]
