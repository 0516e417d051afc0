"""Calibration from recorded files: stream each recording through a :class:`~.pairs.PairCollector`, then fit."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, overload

from necviz.calibration.fit import CalibrationOptions, CalibrationResult, _report, calibrate_collected
from necviz.calibration.pairs import PairCollector
from necviz.core.camera_profile import CameraProfile
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.core.sensor import KNOWN_EVENT_RATES

if TYPE_CHECKING:
    from necviz.calibration.bias_settings import SettingResult


@overload
def calibrate_from_recordings(
    paths,
    options: CalibrationOptions | None = None,
    *,
    exposure_us: float | None = None,
    progress=None,
    bias_setting: None = None,
) -> CalibrationResult: ...


@overload
def calibrate_from_recordings(
    paths,
    options: CalibrationOptions | None = None,
    *,
    exposure_us: float | None = None,
    progress=None,
    bias_setting: int | str,
) -> list[SettingResult]: ...


def calibrate_from_recordings(
    paths,
    options: CalibrationOptions | None = None,
    *,
    exposure_us: float | None = None,
    progress=None,
    bias_setting: int | str | None = None,
) -> CalibrationResult | list[SettingResult]:
    """Calibrate from recorded files (any format :func:`~necviz.drivers.recordings.open_recording` reads).

    Parameters
    ----------
    paths : str, path or sequence of them
        The recordings, streamed one after the other (frames never pair across two of them).
    options : CalibrationOptions, optional
        What to fit, from which start and on which pairs (default: ``CalibrationOptions()``). Its
        ``max_event_rate="auto"`` is 12 Mev/s for DAVIS346 and DAVIS240 frames, else unknown.
    exposure_us : float, optional
        The exposure of formats that do not store it.
    progress : callable, optional
        ``progress(text)`` gets a status line now and then.
    bias_setting : int or "all", optional
        Fit one DVS bias setting of the recordings' bias timeline (a native recording's ``dvs`` notes; 0: the
        biases the data start with) or each one (:mod:`.bias_settings`); ``None``: all the data in one fit.

    Returns
    -------
    CalibrationResult
        Or, with ``bias_setting``, a list of :class:`~.bias_settings.SettingResult` (one per setting fitted).

    Raises
    ------
    ParameterError
        No recording, ``options`` that is not a :class:`CalibrationOptions`, or data without a
        qualifying frame pair (:func:`~necviz.calibration.calibrate_collected`).
    """
    from necviz.drivers.recordings import open_recording

    opts = CalibrationOptions() if options is None else options
    if not isinstance(opts, CalibrationOptions):
        raise ParameterError(f"options must be a CalibrationOptions, got {type(opts).__name__}")
    base = opts.profile or CameraProfile()
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise ParameterError("give at least one recording")
    col = PairCollector(base.crf, opts.selection, opts.collection)
    split = None
    if bias_setting is not None:
        from necviz.calibration.bias_settings import BiasTimeline, SplitCollector

        split = SplitCollector(BiasTimeline(), lambda: PairCollector(base.crf, opts.selection, opts.collection))
    for path in paths:
        rec = open_recording(path, exposure_us=exposure_us)
        if split is not None:
            BiasTimeline.from_annotations(getattr(rec, "annotations", None), split.timeline)
        target = col if split is None else split
        target.begin(str(path))
        t_wall, last, t_first, t_now = time.perf_counter(), 0.0, None, 0
        try:
            for packet in rec:
                target.feed(packet)
                if isinstance(packet, Frame):
                    t_now = packet.exposure_end_us
                    t_first = t_now if t_first is None else t_first
                    now = time.perf_counter()
                    if now - last > 0.5:
                        last = now
                        _report(
                            progress,
                            f"reading {path.name}: {(t_now - t_first) / 1e6:.1f} s, {_frames(target)} frames, "
                            f"{_pairs(target)} pairs kept ({now - t_wall:.0f} s)",
                        )
        finally:
            rec.close()
    if split is not None:
        from necviz.calibration.bias_settings import fit_settings

        split.finish()
        if opts.max_event_rate == "auto":
            shape = next((c.shape for c in split.collectors.values() if c.shape), None)
            opts = replace(opts, max_event_rate=KNOWN_EVENT_RATES.get((shape[1], shape[0])) if shape else None)
        return fit_settings(split, bias_setting, opts, progress=progress)
    col.finish()
    if opts.max_event_rate == "auto":
        rate = KNOWN_EVENT_RATES.get((col.shape[1], col.shape[0])) if col.shape else None
        opts = replace(opts, max_event_rate=rate)
    return calibrate_collected(col, opts, progress=progress)


def _frames(col) -> int:
    cols = getattr(col, "collectors", None)
    return sum(c.frames for c in cols.values()) if cols is not None else col.frames


def _pairs(col) -> int:
    cols = getattr(col, "collectors", None)
    return sum(len(c.pairs) for c in cols.values()) if cols is not None else len(col.pairs)
