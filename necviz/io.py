"""Events in the layouts other Python libraries use, and ``.npz`` exports read back.

necviz's events are a structured array ``t`` int64 µs, ``x``/``y`` uint16, ``p`` int8 (+1 ON, -1 OFF)
(:data:`necviz.core.events.EVENT_DTYPE`). Neighbouring tools name and type the same fields differently:

* `tonic <https://tonic.readthedocs.io>`_ — ``x``, ``y`` int16, ``p`` bool, ``t`` int64 µs, in that
  order (the dtype of its event-camera datasets, e.g. ``tonic.datasets.DVSGesture.dtype``; its
  transforms index fields by name, ``ordering = dtype.names``): :data:`TONIC_DTYPE`;
* `faery <https://github.com/aestream/faery>`_ and the ``aedat`` reader — ``t`` uint64 µs, ``x``,
  ``y`` uint16, ``on`` bool: :data:`FAERY_DTYPE`.

Converting is a copy of four columns (no per-event Python).
"""

from __future__ import annotations

import numpy as np

from necviz.core.events import EVENT_DTYPE

#: tonic's event layout (its DVS datasets' ``dtype``).
TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("p", "?"), ("t", "<i8")])
#: faery's (and ``aedat``'s) event layout.
FAERY_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])


def _check(events: np.ndarray, fields: tuple[str, ...], what: str) -> np.ndarray:
    ev = np.asarray(events)
    if ev.dtype.names is None or any(f not in ev.dtype.names for f in fields) or ev.ndim != 1:
        raise ValueError(f"{what} must be a 1-D structured array with fields {', '.join(fields)}, got {ev.dtype}")
    return ev


def to_tonic(events: np.ndarray) -> np.ndarray:
    """necviz events as tonic expects them.

    Parameters
    ----------
    events : structured array with fields ``t`` (µs), ``x``, ``y``, ``p`` (+1/-1), e.g. ``np.load(f)["events"]``
        of a ``necviz export`` ``.npz``.

    Returns
    -------
    numpy.ndarray
        :data:`TONIC_DTYPE`: ``x``, ``y`` int16, ``p`` True for ON, ``t`` int64 µs; same order and length.

    Raises
    ------
    ValueError
        If a field is missing, or a coordinate does not fit int16 (sensors wider than 32767 pixels).
    """
    ev = _check(events, ("t", "x", "y", "p"), "events")
    if ev.size and max(int(ev["x"].max()), int(ev["y"].max())) > np.iinfo(np.int16).max:
        raise ValueError("coordinates above 32767 do not fit tonic's int16 fields")
    out = np.empty(ev.size, TONIC_DTYPE)
    out["x"], out["y"], out["p"], out["t"] = ev["x"], ev["y"], ev["p"] > 0, ev["t"]
    return out


def to_faery(events: np.ndarray) -> np.ndarray:
    """necviz events as faery (and ``aedat``) store them.

    Parameters
    ----------
    events : structured array with fields ``t`` (µs), ``x``, ``y``, ``p`` (+1/-1).

    Returns
    -------
    numpy.ndarray
        :data:`FAERY_DTYPE`: ``t`` uint64 µs, ``x``, ``y`` uint16, ``on`` True for ON.

    Raises
    ------
    ValueError
        If a field is missing or a timestamp is negative (faery's times are unsigned).
    """
    ev = _check(events, ("t", "x", "y", "p"), "events")
    if ev.size and int(ev["t"].min()) < 0:
        raise ValueError("faery's timestamps are unsigned: shift negative times first")
    out = np.empty(ev.size, FAERY_DTYPE)
    out["t"], out["x"], out["y"], out["on"] = ev["t"], ev["x"], ev["y"], ev["p"] > 0
    return out


def from_tonic(events: np.ndarray) -> np.ndarray:
    """tonic's events (fields ``x``, ``y``, ``t`` µs, ``p`` bool or 0/1) as necviz events, sorted by time.

    Raises
    ------
    ValueError
        If a field is missing.
    """
    ev = _check(events, ("t", "x", "y", "p"), "tonic events")
    out = np.empty(ev.size, EVENT_DTYPE)
    out["t"], out["x"], out["y"] = ev["t"], ev["x"], ev["y"]
    out["p"] = np.where(np.asarray(ev["p"]) > 0, 1, -1)
    return out[np.argsort(out["t"], kind="stable")]


def from_faery(events: np.ndarray) -> np.ndarray:
    """faery's or ``aedat``'s events (``t``, ``x``, ``y``, ``on``) as necviz events.

    Raises
    ------
    ValueError
        If a field is missing.
    """
    ev = _check(events, ("t", "x", "y", "on"), "faery events")
    out = np.empty(ev.size, EVENT_DTYPE)
    out["t"], out["x"], out["y"] = ev["t"], ev["x"], ev["y"]
    out["p"] = np.where(ev["on"], 1, -1)
    return out


def load_npz(path) -> dict:
    """A ``necviz export`` ``.npz`` as a dict of arrays (layout: :mod:`necviz.writers.npz_writer`).

    Parameters
    ----------
    path : the ``.npz`` file.

    Returns
    -------
    dict
        ``events``, ``frames``, ``frame_exposure_start_us``, ``frame_exposure_end_us``, ``frame_gain``,
        ``imu``, ``triggers``, ``sensor_size`` (width, height).

    Raises
    ------
    OSError, ValueError
        If the file is missing or not such an archive.
    """
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


__all__ = ["FAERY_DTYPE", "TONIC_DTYPE", "from_faery", "from_tonic", "load_npz", "to_faery", "to_tonic"]
