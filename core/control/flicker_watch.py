"""Mains flicker at the event bus ceiling: telling a flickering light from a one-way change.

NEC's escape rule (:mod:`necviz.core.control.nec`, case (a)) reads an event window at the bus ceiling
with one polarity dominant as proof that events were lost in that direction, so that the predicted
level is only a bound. A deep mains flicker (a lamp at twice the mains frequency, an LED driver's
pulse train) drives the bus to its ceiling on every swing, ON one half-period and OFF the next: each
window is a "one-sided loss", and the rule aimed the exposure at the near edge of the valid range in
alternating directions every few milliseconds (on a 65 Hz, depth 0.85 scene the exposure alternated
18 ms / 1.8 ms and NEC clipped ten times as many frames as without events).

A one-way change (a light switched, a tunnel exit) drives the bus to its ceiling in *one* direction
for as long as it lasts; a flicker alternates. :class:`FlickerWatch` sees the sequence of ceiling
windows (time, direction) and calls a window *flicker* when

* the direction of the ceiling windows reversed at least ``min_reversals`` times within the last
  ``horizon_us`` (one frame interval of the simulated DAVIS346 at 50 fps: a flicker of 100 Hz and
  more reverses at least four times in it), and
* the current run of same-direction windows has lasted at most ``max_run_us`` (half the period of a
  50 Hz flicker: no mains flicker stays on one side longer; a one-way change under flickering lamps
  that keeps the bus at its ceiling longer than that is again a one-way loss).

A window that is flicker is not a one-sided loss: the swings cancel over a period, and the frames,
which average over their exposure, see the mean. While the light flickers (:meth:`FlickerWatch.active`)
the event-propagated level between frames is the flicker's instantaneous phase, not the level the
next exposure will average: NEC then meters the last frame's exposure-averaged level (as
``nec-frames`` does), until a run of one direction longer than ``max_run_us`` shows a one-way
change or the swings stop. The first swings, seen before the flicker is recognised, started case (a):
when it is recognised, case (a) is withdrawn back to what it was before the sequence began
(:attr:`FlickerWatch.sequence_start_us`). The caller keeps the escape rule's case (b) (a saturated
frame). Designed on the training scenes only
(``benchmarks/training/*.toml``; docs/evaluation.md). O(1) amortised per window.
"""

from __future__ import annotations

from collections import deque

from necviz.core.checks import check_number

#: reversals of the ceiling windows' direction are counted over this long (µs): one frame interval at 50 fps
HORIZON_US = 20_000
#: ... and at least this many make a flicker
MIN_REVERSALS = 2
#: a run of ceiling windows in one direction longer than this (µs) is a one-way change even amid flicker
MAX_RUN_US = 10_000


class FlickerWatch:
    """The sequence of ceiling windows' directions: is the newest one a flicker's swing? (module docstring)

    Parameters
    ----------
    horizon_us : int
        Reversals are counted over this long before the newest window.
    min_reversals : int
        At least this many reversals within ``horizon_us`` make a flicker.
    max_run_us : int
        A run of same-direction windows longer than this is a one-way change.
    """

    def __init__(self, horizon_us: int = HORIZON_US, min_reversals: int = MIN_REVERSALS, max_run_us: int = MAX_RUN_US):
        self.horizon_us = int(check_number("horizon_us", horizon_us, 0.0, lo_open=True))
        self.min_reversals = int(check_number("min_reversals", min_reversals, 1.0))
        self.max_run_us = int(check_number("max_run_us", max_run_us, 0.0, lo_open=True))
        self._reversals: deque[int] = deque()
        self._dir = 0  # direction of the current run (0: none yet)
        self._run_start = 0  # time of the run's first window
        self._last_t: int | None = None
        self.sequence_start_us = 0  # the first window of the current sequence (none more than horizon_us apart)
        self._flicker = False  # the newest window was a flicker's swing
        self.flicker_windows = 0  # windows called flicker (diagnostics)

    def observe(self, t_us: int, direction: int) -> bool:
        """Record a ceiling window ending at ``t_us`` with net polarity ``direction`` (+1 / -1); True if
        it is a flicker's swing (not a one-sided loss)."""
        t = int(t_us)
        stale = self._last_t is None or t - self._last_t > self.horizon_us
        if stale:
            self._reversals.clear()
            self._dir, self._run_start = direction, t
            self.sequence_start_us = t
        elif direction != self._dir:
            self._reversals.append(t)
            self._dir, self._run_start = direction, t
        self._last_t = t
        while self._reversals and self._reversals[0] < t - self.horizon_us:
            self._reversals.popleft()
        flicker = len(self._reversals) >= self.min_reversals and t - self._run_start <= self.max_run_us
        if flicker:
            self.flicker_windows += 1
        self._flicker = flicker
        return flicker

    def active(self, t_us: int) -> bool:
        """True while the light flickers: the newest ceiling window, at most ``horizon_us`` before
        ``t_us``, was a flicker's swing."""
        return self._flicker and self._last_t is not None and int(t_us) - self._last_t <= self.horizon_us
