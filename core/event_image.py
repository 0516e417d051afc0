"""Event images: ON and OFF counts per pixel over a short window, and their colour rendering.

A viewer cannot draw 12 M events/s as points; it can draw ~30 images a second. The dashboard
accumulates each window's events into two count planes and renders them ON = blue-white,
OFF = red (the DAVIS convention in DV/jAER is similar). To bound the work at the sensor's full
rate the accumulation may keep only every ``stride``-th event (decimation, counted by the caller).
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: RGB of an ON event, an OFF event and no event (dark grey background).
ON_RGB = np.array([80, 170, 255], np.float32)
OFF_RGB = np.array([255, 70, 60], np.float32)
BACKGROUND_RGB = np.array([24, 24, 24], np.float32)


@nb.njit(cache=True, nogil=True)
def accumulate_events(x, y, p, counts_on, counts_off, stride):
    """Add every ``stride``-th event to the count planes: ``counts_on[y, x] += 1`` if ``p > 0``
    else ``counts_off[y, x] += 1``. Returns how many events were added.

    O(n / stride); releases the GIL so the dashboard's worker runs beside the control thread.
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


@nb.njit(cache=True, nogil=True)
def render_event_image(counts_on, counts_off, on_rgb, off_rgb, background_rgb, saturate_at, out):
    """Colour each pixel by its net polarity: ``w = min(|on - off| / saturate_at, 1)`` blends the
    background towards the ON or OFF colour. Pixels with equal counts stay background. O(H W)."""
    h, w = counts_on.shape
    for r in range(h):
        for c in range(w):
            d = counts_on[r, c] - counts_off[r, c]
            if d == 0:
                for k in range(3):
                    out[r, c, k] = np.uint8(background_rgb[k])
                continue
            a = min(abs(d) / saturate_at, 1.0)
            col = on_rgb if d > 0 else off_rgb
            for k in range(3):
                out[r, c, k] = np.uint8(background_rgb[k] + a * (col[k] - background_rgb[k]))
    return out


class EventImage:
    """Accumulates events for one window and renders it as an RGB uint8 image (H x W x 3)."""

    def __init__(self, height: int, width: int, saturate_at: float = 2.0):
        self.counts_on = np.zeros((height, width), np.int32)
        self.counts_off = np.zeros((height, width), np.int32)
        self.saturate_at = float(saturate_at)
        self.added = 0

    def add(self, events: np.ndarray, stride: int = 1) -> int:
        n = accumulate_events(events["x"], events["y"], events["p"], self.counts_on, self.counts_off, int(stride))
        self.added += n
        return n

    def render(self) -> np.ndarray:
        out = np.empty(self.counts_on.shape + (3,), np.uint8)
        return render_event_image(self.counts_on, self.counts_off, ON_RGB, OFF_RGB, BACKGROUND_RGB,
                                  self.saturate_at, out)

    def clear(self) -> None:
        self.counts_on.fill(0)
        self.counts_off.fill(0)
        self.added = 0
