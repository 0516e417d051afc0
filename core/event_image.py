"""Event images: ON and OFF counts per pixel over a short window, and their colour rendering.

A viewer cannot draw 12 M events/s as points; it can draw ~30 images a second. The dashboard
accumulates each window's events into two count planes and renders them ON = blue-white,
OFF = red (the DAVIS convention in DV/jAER is similar). To bound the work at the sensor's full
rate the accumulation may keep only every ``stride``-th event (decimation, counted by the caller).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from necviz.core.events import EVENT_DTYPE

#: RGB of an ON event, an OFF event and no event (dark grey background).
ON_RGB = np.array([80, 170, 255], np.float32)
OFF_RGB = np.array([255, 70, 60], np.float32)
BACKGROUND_RGB = np.array([24, 24, 24], np.float32)


@nb.njit(cache=True, nogil=True)
def accumulate_events(x, y, p, counts_on, counts_off, stride):
    """Add every ``stride``-th event to the count planes: ``counts_on[y, x] += 1`` if ``p > 0``
    else ``counts_off[y, x] += 1``. Returns how many events were added.

    O(n / stride); releases the GIL (long arrays; the dashboard's worker draws with
    :func:`accumulate_records`).
    Coordinates are trusted (sources validate them).
    """
    added = 0
    for i in range(0, x.size, stride):
        if p[i] > 0:
            counts_on[y[i], x[i]] += 1
        else:
            counts_off[y[i], x[i]] += 1
        added += 1
    return added


@nb.njit(cache=True)
def accumulate_records(events, counts_on, counts_off, stride):
    """:func:`accumulate_events` on an event array itself (:data:`~necviz.core.events.EVENT_DTYPE`
    records), *holding* the GIL: for a dashboard worker that draws a window from many short batches.

    A kernel that releases the GIL hands it to the control thread on every call, and the worker must
    then wait to take it back (until the control thread releases it, at most the interpreter's switch
    interval, 5 ms): a GIL-bound control thread loses more to the switches than the few µs each
    call runs. Measured with a GIL-bound thread standing in for the control path (2 cores, loaded
    machine): drawing a 33 ms window of 1 ms batches cost that thread 1.6 ms with the releasing kernel
    called per batch, 0.4 ms with this one.
    """
    added = 0
    for i in range(0, events.size, stride):
        e = events[i]
        if e.p > 0:
            counts_on[e.y, e.x] += 1
        else:
            counts_off[e.y, e.x] += 1
        added += 1
    return added


@nb.njit(cache=True)
def zero_counts(counts_on, counts_off):
    """Set both count planes to 0, *holding* the GIL (``ndarray.fill`` releases it on planes this size, and
    a dashboard worker then waits to take it back; see :func:`accumulate_records`). O(H W)."""
    counts_on[:] = 0
    counts_off[:] = 0


def colour_table(on_rgb, off_rgb, background_rgb, saturate_at: float) -> tuple[np.ndarray, int]:
    """Colours for net counts ``d = on - off`` in ``[-K, K]`` (``K = ceil(saturate_at)``): the
    background blended towards the ON (d > 0) or OFF (d < 0) colour by ``min(|d| / saturate_at, 1)``.
    Returns the ``(2K + 1) x 3`` uint8 table and ``K``."""
    k = max(1, int(np.ceil(saturate_at)))
    d = np.arange(-k, k + 1, dtype=np.float32)
    a = np.minimum(np.abs(d) / np.float32(saturate_at), 1.0)[:, None]
    target = np.where(d[:, None] > 0, np.asarray(on_rgb, np.float32), np.asarray(off_rgb, np.float32))
    bg = np.asarray(background_rgb, np.float32)
    return (bg + a * (target - bg)).astype(np.uint8), k


@nb.njit(cache=True, nogil=True, inline="always")
def net_index(on, off, k):
    """A pixel's colour index: its net polarity ``on - off`` clipped to ``[-k, k]``, plus ``k``."""
    d = on - off
    if d > k:
        d = k
    elif d < -k:
        d = -k
    return d + k


@nb.njit(cache=True, nogil=True)
def render_event_image(counts_on, counts_off, table, k, out):
    """``out[r, c] = table[clip(on - off, -k, k) + k]``: each pixel coloured by its net polarity.
    O(H W); releases the GIL."""
    h, w = counts_on.shape
    for r in range(h):
        for c in range(w):
            i = net_index(counts_on[r, c], counts_off[r, c], k)
            out[r, c, 0] = table[i, 0]
            out[r, c, 1] = table[i, 1]
            out[r, c, 2] = table[i, 2]
    return out


@nb.njit(cache=True)
def palette_rows(counts_on, counts_off, k, bits, out):
    """The rows of a paletted PNG (ISO/IEC 15948, filter type 0) of the window: pixel index
    ``clip(on - off, -k, k) + k`` into :func:`colour_table`, ``bits`` (4 or 8) per pixel, two
    4-bit pixels per byte high nibble first (an odd last pixel padded with 0). ``out``:
    ``H x (1 + ceil(W bits / 8))`` uint8, column 0 the filter byte. O(H W), ~0.1 ms on a DAVIS346;
    holds the GIL (see :func:`accumulate_records`: so short a release costs the control thread more
    than it saves)."""
    h, w = counts_on.shape
    for r in range(h):
        out[r, 0] = 0
        for c in range(w):
            i = net_index(counts_on[r, c], counts_off[r, c], k)
            if bits == 8:
                out[r, 1 + c] = i
            elif c % 2 == 0:
                out[r, 1 + c // 2] = i << 4
            else:
                out[r, 1 + c // 2] |= i
    return out


class EventImage:
    """Accumulates events for one window and renders it as an RGB uint8 image (H x W x 3)."""

    def __init__(self, height: int, width: int, saturate_at: float = 2.0):
        self.counts_on = np.zeros((height, width), np.int32)
        self.counts_off = np.zeros((height, width), np.int32)
        self.saturate_at = float(saturate_at)
        self.added = 0
        self._rgb, self._k = colour_table(ON_RGB, OFF_RGB, BACKGROUND_RGB, self.saturate_at)
        self._bgr = np.ascontiguousarray(self._rgb[:, ::-1])

    def add(self, events: np.ndarray, stride: int = 1) -> int:
        n = accumulate_events(events["x"], events["y"], events["p"], self.counts_on, self.counts_off, int(stride))
        self.added += n
        return n

    def add_parts(self, parts, stride: int = 1) -> int:
        """Add every ``stride``-th event of each array in ``parts`` (each counted from its own first
        event, as :meth:`add` would) without releasing the GIL between or inside the parts (see
        :func:`accumulate_records`). Returns how many events were added."""
        n = 0
        on, off, stride = self.counts_on, self.counts_off, int(stride)
        for events in parts:
            if events.dtype == EVENT_DTYPE:
                n += accumulate_records(events, on, off, stride)
            else:  # another layout of the same fields (never from necviz's sources): the field kernel
                n += accumulate_events(events["x"], events["y"], events["p"], on, off, stride)
        self.added += n
        return n

    def render(self, bgr: bool = False) -> np.ndarray:
        """The window as an H x W x 3 uint8 image, RGB (or BGR for OpenCV's encoders)."""
        out = np.empty(self.counts_on.shape + (3,), np.uint8)
        table = self._bgr if bgr else self._rgb
        return render_event_image(self.counts_on, self.counts_off, table, self._k, out)

    def clear(self) -> None:
        zero_counts(self.counts_on, self.counts_off)
        self.added = 0
