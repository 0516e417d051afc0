"""Calibration from recorded files: stream each recording through a :class:`~.pairs.PairCollector`, then fit."""

from __future__ import annotations

import time
from pathlib import Path

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
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.frames import Frame
from necviz.core.sensor import KNOWN_EVENT_RATES

#: Bus ceilings (events/s) assumed for recordings of known sensors (``--max-event-rate auto``).


def calibrate_from_recordings(
    paths,
    *,
    profile: CameraProfile | None = None,
    init: TediParams | None = None,
    fit="all",
    crf: str = "auto",
    exposure_us: float | None = None,
    name: str | None = None,
    max_event_rate="auto",
    slow_rate: float = DEFAULT_SLOW_RATE,
    loss: str = DEFAULT_LOSS,
    f_scale: float = DEFAULT_F_SCALE,
    progress=None,
    max_nfev: int = 200,
    **selection,
) -> CalibrationResult:
    """Calibrate from recorded files (any format :func:`~necviz.drivers.recordings.open_recording` reads).

    ``profile``: the starting profile (response, limits, initial parameters; default DAVIS346);
    ``max_event_rate``: the sensor's bus ceiling in events/s (``"auto"``: 12 Mev/s for DAVIS346 and
    DAVIS240 frames, else unknown; ``None``: unknown), see :func:`calibrate_collected`;
    ``init`` overrides its TEDI parameters as the start; ``fit`` = ``"all"`` (six), ``"c"`` or a
    list of names; ``crf`` = ``"auto"`` (Debevec-Malik when a static exposure bracket is found)
    or ``"keep"``; ``selection``: :class:`PairCollector` options (``min_change``, ``min_pixels``,
    ``max_pixels``, ``max_pairs``, ``max_bytes``, ``max_gap_us``, ``reference``...).
    ``progress(text)`` gets a status line now and then.
    """
    from necviz.drivers.recordings import open_recording

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
                        _report(
                            progress,
                            f"reading {path.name}: {(t_now - t_first) / 1e6:.1f} s, {col.frames} frames, "
                            f"{len(col.pairs)} pairs kept ({now - t_wall:.0f} s)",
                        )
        finally:
            rec.close()
    col.finish()
    if max_event_rate == "auto":
        max_event_rate = KNOWN_EVENT_RATES.get((col.shape[1], col.shape[0])) if col.shape else None
    return calibrate_collected(
        col,
        base=base,
        init=init,
        fit=fit,
        crf_mode=crf,
        name=name,
        max_event_rate=max_event_rate,
        slow_rate=slow_rate,
        loss=loss,
        f_scale=f_scale,
        progress=progress,
        max_nfev=max_nfev,
    )
