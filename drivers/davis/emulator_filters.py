"""The DAVIS FPGA's background-activity and refractory filters, for the emulated camera (issue 29).

What libcaer documents of them (``include/libcaer/devices/davis.h``, DVS parameters 31-34): the
background-activity filter lets through "events that are correlated within this time-frame" (the time in
250 µs units, 0..4095); the refractory filter inhibits a pixel "from generating new events during this time
after the last event has fired". How correlation is judged here follows jAER's ``BackgroundActivityFilter``
(the filter the FPGA's was modelled on): every event stamps its eight neighbours with its time, and an event
passes when its own pixel was stamped within the window. The order (background activity first, then
refractory) is an assumption; the FPGA's source is not public.

Used only with ``EmulatorOptions(fpga_filters=True)``: by default the emulated stream stays the simulator's
events, which tests and benchmarks compare.
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: a time long before any event (no support, no previous event)
NEVER = np.iinfo(np.int64).min // 4


@nb.njit(cache=True, nogil=True)
def fpga_filter(t, x, y, width, height, ba_us, refr_us, support, last, keep, counts):
    """Mark in ``keep`` the events that pass; O(events).

    ``support`` (per pixel) is the last time a neighbour stamped the pixel, ``last`` the pixel's last passed
    event; ``ba_us``/``refr_us`` <= 0 turn a filter off. An event at ``(x, y, t)`` is dropped by the
    background-activity filter when ``t - support[y, x] > ba_us`` (it stamps its neighbours either way), then by
    the refractory filter when ``t - last[y, x] < refr_us``. ``counts`` += (dropped by BA, by refractory).
    """
    n = t.shape[0]
    for i in range(n):
        ti = t[i]
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        k = yi * width + xi
        ok = True
        if ba_us > 0:
            if ti - support[k] > ba_us:
                ok = False
                counts[0] += 1
            for dy in range(-1, 2):
                yy = yi + dy
                if yy < 0 or yy >= height:
                    continue
                for dx in range(-1, 2):
                    xx = xi + dx
                    if (dx != 0 or dy != 0) and 0 <= xx < width:
                        support[yy * width + xx] = ti
        if ok and refr_us > 0:
            if ti - last[k] < refr_us:
                ok = False
                counts[1] += 1
        if ok:
            last[k] = ti
        keep[i] = ok


class FpgaFilters:
    """Per-pixel state of the two filters over one stream (reset when streaming restarts)."""

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)
        self.support = np.full(self.width * self.height, NEVER, np.int64)
        self.last = np.full(self.width * self.height, NEVER, np.int64)
        self.counts = np.zeros(2, np.int64)  # dropped by background activity, by refractory

    def reset(self) -> None:
        self.support[:] = NEVER
        self.last[:] = NEVER

    def apply(self, ev: np.ndarray, ba_us: int, refr_us: int) -> np.ndarray:
        """The events of ``ev`` (EVENT_DTYPE, device time) that pass the enabled filters."""
        if ev.size == 0 or (ba_us <= 0 and refr_us <= 0):
            return ev
        keep = np.empty(ev.size, np.bool_)
        fpga_filter(
            np.ascontiguousarray(ev["t"]),
            np.ascontiguousarray(ev["x"]),
            np.ascontiguousarray(ev["y"]),
            self.width,
            self.height,
            int(ba_us),
            int(refr_us),
            self.support,
            self.last,
            keep,
            self.counts,
        )
        return ev[keep]
