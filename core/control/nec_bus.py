"""NEC's watch on the event bus: case (a) of the escape rule (see :mod:`necviz.core.control.nec`).

A sensor whose event rate is pinned at the bus maximum with one polarity dominant has lost events, so
the true change in that direction is at least the counted one. :class:`BusWatch` pools the event batches
into windows of at least :data:`BUS_WINDOW_US` and flags a window whose rate is at least
:data:`BUS_FRACTION` of the ceiling and whose net polarity is at least :data:`POLARITY_DOMINANCE` of its
events. A window that a :class:`~necviz.core.control.flicker_watch.FlickerWatch` calls a flicker's swing
is not a loss: it leaves case (a) as it was before the flicker's sequence began. O(1) per batch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from necviz.core.crf import US_PER_S

if TYPE_CHECKING:
    from necviz.core.control.flicker_watch import FlickerWatch

__all__ = ["BUS_FRACTION", "BUS_WINDOW_US", "POLARITY_DOMINANCE", "BusWatch"]

#: a window of events is "at the ceiling" when its rate is at least this fraction of the bus maximum
BUS_FRACTION = 0.9
#: ... and one polarity dominates: |ON - OFF| at least this fraction of its events
POLARITY_DOMINANCE = 0.6
#: the event rate is judged over windows of at least this long (µs; shorter batches are pooled)
BUS_WINDOW_US = 500


class BusWatch:
    """Windows of events at the bus ceiling (see the module docstring).

    Attributes
    ----------
    saturated_t : int
        The last event time of the last window found at the ceiling (the int64 minimum: none yet).
    saturated_dir : int
        That window's dominant polarity: +1 ON (the light rose), -1 OFF, 0 none yet.
    saturated_windows : int
        Windows found at the ceiling so far (diagnostics).
    """

    def __init__(self) -> None:
        self.saturated_t = np.iinfo(np.int64).min
        self.saturated_dir = 0
        self.saturated_windows = 0
        self._t0: int | None = None  # the open window's start (None: before the first batch)
        self._n = 0  # events in the open window
        self._net = 0  # their net polarity (ON - OFF) in the region
        self._up = 0  # their ON events in the region
        self._seen = (0, 0)  # the region's ON/OFF totals at the last batch
        self._before = (self.saturated_t, self.saturated_dir)  # case (a) before the current flicker sequence

    def watch(
        self, n: int, t_last: int, totals: tuple[int, int], rate: float, flicker: FlickerWatch | None = None
    ) -> tuple[int, int] | None:
        """A batch of ``n`` events ending at ``t_last``; ``totals``: the region's ON/OFF events counted so far;
        ``rate``: the bus ceiling (events/s); ``flicker``: the watch that tells a flicker's swing (None: every
        ceiling window is a loss). Returns the ``(ON, OFF)`` region events of a window that closes at the
        ceiling with one polarity dominant and is not a flicker's swing, else ``None``."""
        on, off = totals
        d_on = on - self._seen[0]
        d_off = off - self._seen[1]
        self._seen = (on, off)
        if self._t0 is None:
            self._t0 = t_last
            return None
        self._n += n
        self._net += d_on - d_off  # net polarity of the region's events
        self._up += d_on
        span = t_last - self._t0
        if span < BUS_WINDOW_US:
            return None
        hit = None
        if self._n >= BUS_FRACTION * rate * span / US_PER_S and abs(self._net) >= POLARITY_DOMINANCE * self._n:
            self.saturated_windows += 1
            d = 1 if self._net > 0 else -1
            if flicker is not None and flicker.observe(t_last, d):  # a flicker's swing loses nothing
                if self.saturated_t >= flicker.sequence_start_us:  # its first swings, taken for losses
                    self.saturated_t, self.saturated_dir = self._before
            else:
                if flicker is not None and flicker.sequence_start_us == t_last:
                    self._before = (self.saturated_t, self.saturated_dir)
                self.saturated_t = t_last
                self.saturated_dir = d
                hit = (self._up, self._up - self._net)
        self._t0 = t_last
        self._n = 0
        self._net = 0
        self._up = 0
        return hit
