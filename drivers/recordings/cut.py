"""Cutting a recording by time: ``--start``/``--end`` in seconds from its first timestamp.

A cut holds exactly what lies in ``[first + start, first + end)``: the events, IMU samples and
triggers stamped inside that half-open interval, and the frames whose whole exposure lies in it
(exposure start at or after ``first + start``, exposure end at or before ``first + end``).
``first`` is the recording's earliest timestamp of any kind (the first packet in stream order:
an event, an IMU sample, a trigger or an exposure start), so ``--start 0`` keeps everything.
Seconds become microseconds by rounding *up* (:func:`offset_us`): for integer timestamps,
``t - first >= start`` exactly when ``t - first >= ceil(start)``, and ``t - first < end`` when
``t - first < ceil(end)``; ``--end 1e-7`` therefore keeps what is stamped at ``first`` itself.
"""

from __future__ import annotations

import math

from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch


def offset_us(seconds: float) -> int:
    """``seconds`` as whole µs, rounded up (after rounding away float noise below a nanosecond:
    ``0.05 * 1e6`` is 50000.000000000007, which is 50,000 µs, not 50,001)."""
    return int(math.ceil(round(float(seconds) * 1e6, 3)))


def packet_start_us(packet) -> int | None:
    """The earliest time a packet carries (events and samples: the first; a frame: its exposure start)."""
    match packet:
        case EventBatch():
            return int(packet.events["t"][0]) if len(packet) else None
        case ExposureMarker():
            return int(packet.t_us)
        case Frame():
            return int(packet.exposure_start_us)
        case ImuBatch():
            return int(packet.samples["t"][0]) if len(packet) else None
        case TriggerBatch():
            return int(packet.triggers["t"][0]) if len(packet) else None
    return None


def first_time_us(path, **open_kwargs) -> int | None:
    """The first timestamp of the recording at ``path`` (its first packet in stream order), or None
    when it holds nothing. Opens it briefly: readers stream, so this reads one packet."""
    from necviz.drivers.recordings import open_recording

    rec = open_recording(path, **open_kwargs)
    try:
        for packet in rec:
            t = packet_start_us(packet)
            if t is not None:
                return t
        return None
    finally:
        rec.close()


def open_cut(path, start_s: float | None = None, end_s: float | None = None, **open_kwargs):
    """Open ``path`` restricted to ``[first + start_s, first + end_s)`` (module docstring).

    Returns ``(recording, first_us)``; ``first_us`` is None for a recording that holds nothing.
    """
    from necviz.drivers.recordings import open_recording

    origin = first_time_us(path, **open_kwargs)
    if origin is None:
        return open_recording(path, **open_kwargs), None
    start_us = None if start_s is None else origin + offset_us(start_s)
    end_us = None if end_s is None else origin + offset_us(end_s)
    return open_recording(path, start_us=start_us, end_us=end_us, **open_kwargs), origin


__all__ = ["first_time_us", "offset_us", "open_cut", "packet_start_us"]
