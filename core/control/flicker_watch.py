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
frame).

**Edges** (``edges``, NEC's ``flicker_edges``). A lamp need not drive the bus to its ceiling on both
swings, nor on every period: a PWM lamp's rising and falling edges give different event counts (the ON
and OFF thresholds differ), a shallow lamp reaches the ceiling only on the swing that a switched light's
ramp adds to, and a lamp near the ceiling's threshold reaches it on some periods only. Then the ceiling
windows do not alternate within a frame interval, and each was read as a one-way loss: the escape rule
aimed the exposure at the near edge of the valid range (2.6 times the goal's exposure for a loss
downwards) and the next frame clipped 15-35 % of its pixels (``benchmarks/training/pwm_bright_06.toml``:
a 7 dB switch ramping over 49 ms under a 120 Hz lamp drove the bus to its ceiling for one 1 ms window
once a period, and NEC clipped 3.2 frames over 10 % per run where ``nec-frames`` clipped none). What sets
such windows apart from a one-way loss is their length: a lamp's edge keeps the bus at its ceiling for a
fraction of a period (a PWM edge, 5 % of a period, gave bursts of one or two 1 ms windows on every
training scene), a change that outruns the bus keeps it there for as long as it lasts (a light switched
in 2 ms: 2-3 ms). So the windows are grouped into *bursts* (windows of one direction at most
:data:`BURST_GAP_US` apart), and a window is also a flicker's swing when its burst has lasted at most
``max_edge_us`` and the burst before it, of either direction, was as short and ended at most
``memory_us`` before this one began (two frame intervals: a lamp that reached the ceiling a moment ago
still flickers). A single short burst (a light switched in a millisecond) stays a loss, as does every
window of a burst that outlasts ``max_edge_us``, and the burst right after a longer one. Like the
reversals, an edge withdraws the case (a) that its sequence's first windows started. What an edge costs
when it was really a short loss: NEC meters the last frame's level, as ``nec-frames`` does, until the
next frame or a saturated frame's case (b). Designed on the training scenes only
(``benchmarks/training/*.toml``; docs/evaluation.md, "Edges"). O(1) amortised per window.
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
#: ceiling windows of one direction at most this far apart (µs) are one burst (``edges``)
BURST_GAP_US = 2_000
#: a burst at the ceiling that lasts at most this long (µs) may be a lamp's edge (``edges``)
MAX_EDGE_US = 1_500
#: ... and is one when the burst before it was as short and ended at most this long before it (µs)
MEMORY_US = 40_000


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
    edges : bool
        Also call a window a flicker's swing when its burst and the burst before it are a lamp's edges
        (module docstring, "Edges").
    max_edge_us, memory_us : int
        The longest burst that may be an edge, and how long after the previous short burst it may begin.
    """

    def __init__(
        self,
        horizon_us: int = HORIZON_US,
        min_reversals: int = MIN_REVERSALS,
        max_run_us: int = MAX_RUN_US,
        edges: bool = False,
        max_edge_us: int = MAX_EDGE_US,
        memory_us: int = MEMORY_US,
    ):
        self.horizon_us = int(check_number("horizon_us", horizon_us, 0.0, lo_open=True))
        self.min_reversals = int(check_number("min_reversals", min_reversals, 1.0))
        self.max_run_us = int(check_number("max_run_us", max_run_us, 0.0, lo_open=True))
        self.edges = bool(edges)
        self.max_edge_us = int(check_number("max_edge_us", max_edge_us, 0.0, lo_open=True))
        self.memory_us = int(check_number("memory_us", memory_us, 0.0, lo_open=True))
        # bursts (edges): the current one's direction, first and last window; the end of the one before it
        # when it was short (None: none, or a long one)
        self._burst_dir = 0
        self._burst_start = 0
        self._burst_last: int | None = None
        self._short_end: int | None = None
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
        edge = self._edge(t, direction)
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
        flicker = edge or (len(self._reversals) >= self.min_reversals and t - self._run_start <= self.max_run_us)
        if flicker:
            self.flicker_windows += 1
        self._flicker = flicker
        return flicker

    def _edge(self, t: int, direction: int) -> bool:
        """Track the bursts; True if the window at ``t`` is a lamp's edge (``edges``; module docstring)."""
        last = self._burst_last
        if last is None or direction != self._burst_dir or t - last > BURST_GAP_US:  # a new burst
            if last is not None:
                self._short_end = last if last - self._burst_start <= self.max_edge_us else None
            self._burst_dir, self._burst_start = direction, t
        self._burst_last = t
        if not self.edges or self._short_end is None:
            return False
        return t - self._burst_start <= self.max_edge_us and self._burst_start - self._short_end <= self.memory_us

    def active(self, t_us: int) -> bool:
        """True while the light flickers: the newest ceiling window, at most ``horizon_us`` before
        ``t_us``, was a flicker's swing."""
        return self._flicker and self._last_t is not None and int(t_us) - self._last_t <= self.horizon_us
