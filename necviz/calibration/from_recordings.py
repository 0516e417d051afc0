"""Calibration from recorded files: stream each recording through a :class:`~.pairs.PairCollector`, then fit."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from necviz.calibration.fit import CalibrationOptions, CalibrationResult, _report, calibrate_collected
from necviz.calibration.pairs import PairCollector
from necviz.core.camera_profile import CameraProfile
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.core.sensor import KNOWN_EVENT_RATES


def calibrate_from_recordings(
    paths, options: CalibrationOptions | None = None, *, exposure_us: float | None = None, progress=None
) -> CalibrationResult:
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

    Returns
    -------
    CalibrationResult

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
                        _report(
                            progress,
                            f"reading {path.name}: {(t_now - t_first) / 1e6:.1f} s, {col.frames} frames, "
                            f"{len(col.pairs)} pairs kept ({now - t_wall:.0f} s)",
                        )
        finally:
            rec.close()
    col.finish()
    if opts.max_event_rate == "auto":
        rate = KNOWN_EVENT_RATES.get((col.shape[1], col.shape[0])) if col.shape else None
        opts = replace(opts, max_event_rate=rate)
    return calibrate_collected(col, opts, progress=progress)
