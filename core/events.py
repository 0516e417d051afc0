"""Event arrays: the structured NumPy type every necviz component exchanges.

An event array is a 1-D structured array with fields ``t`` (int64, microseconds),
``x``, ``y`` (uint16, pixel column and row) and ``p`` (int8, +1 ON / -1 OFF),
sorted by ``t`` (ties allowed), following tonic's field naming. Between a source and its
consumers an event array travels as an :class:`EventBatch` packet (its ``events``), never bare.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from necviz.core.errors import EventFormatError
from necviz.core.sensor import SensorGeometry

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])


@dataclass(frozen=True, slots=True, eq=False)
class EventBatch:
    """Events as a stream packet: an :data:`EVENT_DTYPE` batch in time order.

    Sources yield event batches beside exposure markers, frames, IMU and trigger batches; a typed
    packet lets every consumer tell them apart with one ``match`` (:func:`necviz.core.stream.dispatch`)
    instead of asking whether a packet is an array. Every camera of a source shares its batches.
    """

    events: np.ndarray

    def __len__(self) -> int:
        return len(self.events)

    @property
    def t_last_us(self) -> int | None:
        """Time of the last event (``None`` for an empty batch)."""
        return int(self.events["t"][-1]) if len(self.events) else None


def empty_events() -> np.ndarray:
    """A valid batch with no events."""
    return np.zeros(0, dtype=EVENT_DTYPE)


def make_events(t, x, y, p, sensor: SensorGeometry | None = None) -> np.ndarray:
    """Build a validated event batch from four equal-length sequences.

    ``t`` must be integral microseconds (integers, or floats with no fractional part),
    ``p`` must hold only +1 and -1 (``True``/``False`` or 1/0 are *not* accepted,
    to catch a 0/1 polarity convention silently read as OFF).
    """
    arrays = [np.asarray(a) for a in (t, x, y, p)]
    n = arrays[0].shape
    for name, a in zip("txyp", arrays, strict=True):
        if a.ndim != 1:
            raise EventFormatError(f"event field '{name}' must be 1-D, got shape {a.shape}")
        if a.shape != n:
            raise EventFormatError(f"event fields have different lengths: t has {n[0]}, {name} has {a.shape[0]}")
        if a.size and not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
            raise EventFormatError(f"event field '{name}' must be numeric, got dtype {a.dtype}")
    t, x, y, p = arrays
    if t.size and np.issubdtype(t.dtype, np.floating):
        if not np.all(np.isfinite(t)) or np.any(t != np.round(t)):
            raise EventFormatError("event times must be whole microseconds (got non-integral or NaN values)")
    for name, a in (("x", x), ("y", y)):
        if a.size and (np.any(a < 0) or np.any(a > 65535) or np.any(a != np.round(a))):
            raise EventFormatError(f"event coordinate '{name}' must be integers in 0..65535")
    if p.size and np.any((p != 1) & (p != -1)):
        bad = np.unique(p[(p != 1) & (p != -1)])[:5]
        raise EventFormatError(f"event polarity must be +1 or -1, found {bad.tolist()}")
    ev = np.empty(n[0], dtype=EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = t, x, y, p
    validate_events(ev, sensor)
    return ev


def validate_events(events: np.ndarray, sensor: SensorGeometry | None = None) -> np.ndarray:
    """Check an event batch; return it unchanged or raise :class:`EventFormatError`.

    Checks the exact dtype, that time never decreases, that polarity is ±1 and,
    when ``sensor`` is given, that every coordinate lies on the sensor.
    Cost: a few vectorised passes, O(n).
    """
    if not isinstance(events, np.ndarray):
        raise EventFormatError(f"events must be a NumPy structured array, got {type(events).__name__}")
    if events.dtype != EVENT_DTYPE:
        raise EventFormatError(
            f"events have dtype {events.dtype}, expected {EVENT_DTYPE} "
            "(t int64 µs, x/y uint16, p int8 ±1); build them with necviz.core.events.make_events"
        )
    if events.ndim != 1:
        raise EventFormatError(f"events must be a 1-D array, got shape {events.shape}")
    if events.size == 0:
        return events
    t = events["t"]
    if events.size > 1:
        back = np.flatnonzero(t[1:] < t[:-1])
        if back.size:
            i = int(back[0])
            raise EventFormatError(
                f"event times must not decrease: event {i + 1} at {int(t[i + 1])} µs follows {int(t[i])} µs"
            )
    p = events["p"]
    if np.any((p != 1) & (p != -1)):
        raise EventFormatError("event polarity must be +1 or -1")
    if sensor is not None:
        if int(events["x"].max()) >= sensor.width or int(events["y"].max()) >= sensor.height:
            xs, ys = events["x"], events["y"]
            i = int(np.flatnonzero((xs >= sensor.width) | (ys >= sensor.height))[0])
            raise EventFormatError(
                f"event {i} at (x={int(xs[i])}, y={int(ys[i])}) lies outside the {sensor.width}x{sensor.height} sensor"
            )
    return events
