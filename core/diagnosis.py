"""Why did a frame saturate? One cause per saturated frame, from the data (and the simulator's ground truth).

A frame is saturated when more than half of its pixels clip at one end (the paper's threshold);
its *direction* ``d`` is +1 when it clipped at the top (over-exposed), -1 at the bottom. Given
what is known about the frame (:class:`Evidence`), :func:`diagnose` applies the rules below in
order and names the first that holds; the order goes from what no controller could have avoided
to what the controller chose:

1. ``change_during_exposure`` (:func:`rule_change_during_exposure`): the light crossed into the
   saturating range after the exposure had started; no command can change a running exposure.
2. ``command_latency`` (:func:`rule_command_latency`): it crossed less than the camera's command
   latency before the exposure started, so no command issued after the change could take effect;
   or the controller's first correcting command after the change was issued in that window.
3. ``limit_reached`` (:func:`rule_limit_reached`): the exposure (and gain) was already at the limit
   in the direction that would have helped: the shortest exposure at gain 1 for an over-exposed
   frame, the longest at the highest gain for an under-exposed one. (A scene's dynamic range alone
   never forces a saturated frame: an exposure that records the median pixel validly clips at most
   half at either end; the residual's explanation says how much any single exposure could record.)
4. ``prediction_undercount`` (:func:`rule_prediction_undercount`): a controller whose estimator
   received events (counted as delivered, not declared) set the exposure from P-TEDI's prediction, the frame proves the prediction missed part of the
   change — P-TEDI's change since its anchor falls short of the frame's by more than
   :data:`UNDERCOUNT_LN` (the frame clipped at one end only, :data:`ONE_SIDED`, so that its
   estimate is a bound) — *and* the events the sensor lost at its bus ceiling in that time
   (the simulator's count, in the ground truth) carried at least :data:`LOST_EXPLAINS` of that
   shortfall. A lane without events never gets it; nor does a miss that lost events do not
   explain (a compensation that does not match the sensor, say: the residual names it).
5. ``controller_lag`` (:func:`rule_controller_lag`): the controller's first correcting command came
   only with the first frame that showed the change, and that frame was read out too late for a
   command to take effect on this exposure: the measured timing of its commands, the same rule for
   every controller (an event-driven one that waited for a frame lags too).
6. ``controller`` (:func:`rule_controller`): none of the above — the controller's choice with
   what it knew (a metering statistic that loses a two-level scene, a controller that never
   reacts, a replayed camera's own exposure control).

Timing evidence. With ground truth (simulated frames, :class:`~necviz.core.ground_truth.GroundTruth`)
the rules use the *saturating light level* of the frame's setting. Modelling a change of the
light as a global factor on the frame's true exposure-averaged irradiance ``Lbar(x)``, more than
half of its pixels clip at the top when the scene's mean ``ln L`` exceeds ``Λ = μ - median(ln Lbar) + ln L_hi`` (``μ``
the frame's mean ``ln Lbar``, ``L_hi`` the irradiance that records 249.5 DN at this exposure and
gain; at the bottom: below ``μ - median(ln Lbar) + ln L_lo``). The time the scene's lighting
trace last crossed ``Λ`` (linear between rendered samples) is the change's onset for this frame.
Without ground truth (cameras, files) the onset is estimated from the data: events during the
exposure (P-TEDI's ``ln E_p(s)``, the exposure-mean irradiance relative to its start, beyond
:data:`EXPOSURE_CHANGE_LN`) mean the light changed during it; a command that would have
corrected the frame, issued within the latency before the start, means the reaction came too late.

Every rule returns an explanation carrying its numbers (times in ms, changes in natural-log
units of irradiance), or ``None`` when it does not hold; the explanation is meant to be read
after its cause (``command_latency: the light rose +2.10 ln 0.7 ms before the exposure started;
commands take effect 1.0 ms after they are issued``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from necviz.core.ground_truth import TRACE_STEP, GroundTruth

#: The causes, in the order the rules are applied (stable strings: JSON keys and recording text).
CAUSES = (
    "change_during_exposure",
    "command_latency",
    "limit_reached",
    "prediction_undercount",
    "controller_lag",
    "controller",
)

#: A prediction "under-counts" when the frame proves it missed at least this much (ln units, ≈ 4.3 dB,
#: a factor 1.65) of the change: the frame's estimate of ln P(s) is a one-sided bound when it is
#: saturated, so the true shortfall is at least this.
UNDERCOUNT_LN = 0.5
#: Events lost at the bus ceiling "explain" a prediction's shortfall when the log change they carried
#: (towards the saturation) is at least this fraction of the shortfall the frame proves.
LOST_EXPLAINS = 0.5
#: Without ground truth, the light "changed during the exposure" when the events show the exposure's
#: mean irradiance at least this far (ln units) from its value at the start, towards the saturation.
EXPOSURE_CHANGE_LN = 0.5
#: A command "corrects" a frame when its exposure-gain product is at least this far (ln units) from
#: the frame's, in the direction that reduces the clipping.
CORRECTION_LN = 0.1
#: An exposure within this relative distance of a limit is at the limit (the simulator rounds
#: exposures to whole µs).
AT_LIMIT = 0.01
#: A saturated frame bounds the light one-sidedly only if its other end clipped at most this
#: fraction (P-TEDI's own rule for its saturation bound): clipped at both ends, its mean is lowered
#: at one end and raised at the other and proves nothing.
ONE_SIDED = 0.05


@dataclass(frozen=True)
class Command:
    """A command the lane issued: at ``issue_us`` (sensor time), exposure µs and linear gain."""

    issue_us: int
    exposure_us: float
    gain: float


@dataclass(frozen=True)
class Evidence:
    """Everything known about one saturated frame (NaN / ``None`` where unknown).

    ``start_us``/``end_us``, ``exposure_us``, ``gain``: the frame's exposure. ``over``/``under``:
    its clipped fractions. ``truth``: simulator ground truth (``None`` for real frames).
    ``exposure_min_us``/``exposure_max_us``/``gain_max``: the limits that applied (the tighter
    of the controller's and the camera's). ``latency_us``: a command takes effect at the first
    exposure starting at least this long after its issue. ``sees_events``: events reached the
    controller's estimator between the lane's previous frame and this one (counted where they were
    delivered, never taken from what the controller declares: ``nec-frames`` and every baseline
    receive none, NEC on a source without events none either). ``drives``: the lane's commands set this camera's exposure
    (``False`` in a replay). ``commands``: the lane's recent commands, oldest first.
    ``predicted_change``: P-TEDI's ln P(s) minus its anchor then; ``frame_change``: the frame's own
    estimate of ln P(s) (a bound when saturated) minus the same anchor. ``exposure_log_change``:
    P-TEDI's ln E_p(s) for this exposure. ``frame_interval_us``: the camera's frame period.
    ``previous_saturated``: the lane's previous frame clipped more than half in the same direction
    (``None`` when there is none). ``recent_frames``: ``(start_us, end_us, exposure-gain product)``
    of the lane's last few frames before this one, oldest first. ``lost_change``: the sensor-mean
    log change carried by the events lost at the bus ceiling between P-TEDI's anchor and the
    exposure's end (ground truth; NaN where unknown, e.g. a recording).
    """

    sequence: int
    start_us: int
    end_us: int
    exposure_us: float
    gain: float
    over: float
    under: float
    truth: GroundTruth | None = None
    exposure_min_us: float | None = None
    exposure_max_us: float | None = None
    gain_max: float | None = None
    latency_us: float | None = None
    sees_events: bool | None = None
    drives: bool | None = None
    commands: tuple = ()
    predicted_change: float = math.nan
    frame_change: float = math.nan
    exposure_log_change: float = math.nan
    frame_interval_us: float | None = None
    previous_saturated: bool | None = None
    recent_frames: tuple = ()
    lost_change: float = math.nan

    @property
    def direction(self) -> int:
        """+1: clipped at the top (over-exposed); -1: at the bottom."""
        return 1 if self.over >= self.under else -1

    @property
    def kind(self) -> str:
        return "over" if self.direction > 0 else "under"


# ---------------------------------------------------------------------------------------------
# timing from the ground truth
# ---------------------------------------------------------------------------------------------
def saturating_level(truth: GroundTruth, exposure_us: float, gain: float, direction: int) -> float:
    """``Λ``: the scene mean ``ln L`` beyond which more than half the frame's pixels clip (in ``direction``).

    A global light change by ``δ`` moves every pixel's ``ln Lbar`` by ``δ``; more than half clip at the
    top when ``median(ln Lbar) + δ >= ln L_hi``, i.e. when the scene's level ``μ + δ`` exceeds
    ``μ - median + ln L_hi`` (``μ``: the frame's mean ``ln Lbar``, the level on the trace's scale).
    """
    sub = truth.mean_irradiance[::TRACE_STEP, ::TRACE_STEP]
    med = float(np.log(max(float(np.median(sub)), 1e-30)))
    lo, hi = truth.bounds(exposure_us, gain)
    return truth.log_mean() - med + math.log(hi if direction > 0 else lo)


def crossing_time(truth: GroundTruth, level: float, direction: int, until_us: int) -> tuple[float | None, str]:
    """``(onset, state)``: the last time at or before ``until_us`` the lighting trace crossed ``level``
    into the saturating side (``direction``), linear between samples, with ``state = "crossed"``;
    ``(None, "throughout")`` when the trace was on that side from its start (the light saturated
    this setting before the trace's look-back); ``(None, "not_reached")`` when it never got there
    (the saturation is not a global light level: a change of the scene's pattern)."""
    t = truth.light_t_us.astype(np.float64)
    if t.size == 0:
        return None, "not_reached"
    v = direction * (truth.light_log - level)  # > 0: saturating
    k = int(np.searchsorted(t, until_us, side="right"))
    tt, vv = [float(x) for x in t[:k]], [float(x) for x in v[:k]]
    if not tt or tt[-1] < until_us:  # end with the interpolated value at until_us
        tt.append(float(until_us))
        vv.append(float(direction * (truth.light_at(until_us) - level)))
    ups = [i for i in range(1, len(vv)) if vv[i] > 0 >= vv[i - 1]]
    if not ups:
        return None, ("throughout" if vv[0] > 0 else "not_reached")
    i = ups[-1]
    a, b = vv[i - 1], vv[i]
    return tt[i - 1] + (tt[i] - tt[i - 1]) * (-a / (b - a)), "crossed"


@dataclass(frozen=True)
class Timing:
    """When the light crossed into the frame's saturating range (``onset_us``), how much it changed
    across the exposure and across the latency window before it (ln units), and where it came from."""

    onset_us: float | None
    change_exposure: float
    change_latency: float
    source: str  # "ground truth" or "data"
    label: str = ""
    state: str = "crossed"  # see crossing_time


def truth_timing(ev: Evidence) -> Timing | None:
    """The onset from the ground-truth lighting trace (``None`` without truth)."""
    tr = ev.truth
    if tr is None or tr.light_t_us.size == 0:
        return None
    d = ev.direction
    level = saturating_level(tr, ev.exposure_us, ev.gain, d)
    onset, state = crossing_time(tr, level, d, ev.end_us)
    lat = ev.latency_us if ev.latency_us is not None else tr.latency_us
    at_s = tr.light_at(ev.start_us)
    label = ""
    if onset is not None:
        near = [
            c
            for c in tr.changes
            if abs(c.t_us - onset) <= max(ev.frame_interval_us or 0, ev.end_us - ev.start_us, 50_000)
        ]
        if near:
            label = min(near, key=lambda c: abs(c.t_us - onset)).label
    return Timing(
        onset, tr.light_at(ev.end_us) - at_s, at_s - tr.light_at(ev.start_us - lat), "ground truth", label, state
    )


def _ms(us: float) -> str:
    return f"{us / 1e3:.1f} ms"


def _ln(x: float) -> str:
    return f"{x:+.2f} ln" if math.isfinite(x) else "unknown"


def _correcting(ev: Evidence, cmd: Command) -> bool:
    """The command moves the exposure-gain product away from the clipping by at least CORRECTION_LN."""
    step = math.log(cmd.exposure_us * cmd.gain) - math.log(ev.exposure_us * ev.gain)
    return -ev.direction * step >= CORRECTION_LN


def _light(ev: Evidence) -> str:
    return "rose" if ev.direction > 0 else "fell"


# ---------------------------------------------------------------------------------------------
# the rules, in order
# ---------------------------------------------------------------------------------------------
def rule_change_during_exposure(ev: Evidence, timing: Timing | None) -> str | None:
    """The light crossed into the saturating range after the exposure started (ground truth), or the
    events during the exposure show its mean irradiance at least :data:`EXPOSURE_CHANGE_LN` beyond
    its value at the start, towards the saturation (data)."""
    s, e = ev.start_us, ev.end_us
    if timing is not None and timing.source == "ground truth":
        if timing.onset_us is not None and s < timing.onset_us <= e:
            what = f" ({timing.label})" if timing.label else ""
            return (
                f"the light {_light(ev)} {_ln(timing.change_exposure)} during the "
                f"{_ms(e - s)} exposure{what}, crossing the level this exposure could hold "
                f"{_ms(timing.onset_us - s)} after it started"
            )
        return None
    x = ev.exposure_log_change
    if math.isfinite(x) and ev.direction * x >= EXPOSURE_CHANGE_LN:
        return (
            f"the events show the light {_light(ev)} during the {_ms(e - s)} "
            f"exposure (exposure-mean irradiance {_ln(x)} from its start)"
        )
    return None


def rule_command_latency(ev: Evidence, timing: Timing | None) -> str | None:
    """No command issued after the change could take effect on this exposure: the light crossed
    into the saturating range less than the command latency before the exposure started (ground
    truth), or the controller's first correcting command after the change was issued in that window
    (ground truth: after the onset, none before the window; data: a correcting command in the window)."""
    lat = ev.latency_us
    if lat is None or lat <= 0 or ev.drives is False:
        return None
    s = ev.start_us
    window = s - lat
    fixes = [c for c in ev.commands if c.issue_us <= s and _correcting(ev, c)]
    late = [c for c in fixes if c.issue_us > window]
    if timing is not None and timing.source == "ground truth":
        on = timing.onset_us
        if on is None or on > s:
            return None
        what = f" ({timing.label})" if timing.label else ""
        if on > window:
            msg = (
                f"the light {_light(ev)} {_ln(timing.change_latency)}{what} "
                f"{_ms(s - on)} before the exposure started; commands take effect {_ms(lat)} after they are issued"
            )
        elif late and late[0].issue_us >= on and not any(on <= c.issue_us <= window for c in fixes):
            msg = (
                f"the light {_light(ev)}{what} {_ms(s - on)} before the exposure started; the "
                f"controller's first correcting command came {_ms(late[0].issue_us - on)} after the change, "
                f"{_ms(s - late[0].issue_us)} before the exposure started; commands take effect {_ms(lat)} after "
                "they are issued"
            )
            return msg + f" (it commanded {late[0].exposure_us:.0f} µs × {late[0].gain:.3g})"
        else:
            return None
    elif late:
        msg = (
            f"a correcting command was issued {_ms(s - late[0].issue_us)} before the exposure "
            f"started; commands take effect {_ms(lat)} after they are issued"
        )
    else:
        return None
    if late:
        c = late[0]
        msg += f" (the controller commanded {c.exposure_us:.0f} µs × {c.gain:.3g} at {_ms(c.issue_us - s)})"
    return msg


def best_valid_fraction(truth: GroundTruth) -> float:
    """The largest fraction of the frame's pixels any single exposure would record valid: the most
    pixels whose ``ln Lbar`` fit in a window as wide as the sensor's valid range
    (``g(249.5) - g(9.5)``), on the grid of :data:`~necviz.core.ground_truth.TRACE_STEP`."""
    lo, hi = truth.bounds(1e6, 1.0)
    width = math.log(hi) - math.log(lo)
    v = np.sort(np.log(np.maximum(truth.mean_irradiance[::TRACE_STEP, ::TRACE_STEP].ravel(), 1e-30)))
    if v.size == 0:
        return math.nan
    end = np.searchsorted(v, v + width, side="left")  # pixels in [v_i, v_i + width)
    return float((end - np.arange(v.size)).max()) / v.size


def rule_limit_reached(ev: Evidence, timing: Timing | None = None) -> str | None:
    """The setting was at the camera's (or controller's) limit in the direction that would have
    helped: minimum exposure at gain 1 for an over-exposed frame, maximum exposure at the highest
    gain for an under-exposed one (within :data:`AT_LIMIT`)."""
    if ev.direction > 0:
        lo = ev.exposure_min_us
        if lo is None or ev.exposure_us > lo * (1 + AT_LIMIT) + 0.5 or ev.gain > 1.0 + AT_LIMIT:
            return None
        return (
            f"the exposure was at its minimum ({ev.exposure_us:.0f} µs, limit {lo:g} µs) at gain "
            f"{ev.gain:.3g} and the frame still clipped {ev.over:.0%} of its pixels at the top"
        )
    hi, gmax = ev.exposure_max_us, ev.gain_max
    if hi is None or gmax is None or ev.exposure_us < hi * (1 - AT_LIMIT) or ev.gain < gmax * (1 - AT_LIMIT):
        return None
    return (
        f"the exposure was at its maximum ({ev.exposure_us:.0f} µs, limit {hi:g} µs) at the highest "
        f"gain ({ev.gain:.3g}) and the frame still clipped {ev.under:.0%} of its pixels at the bottom"
    )


def rule_prediction_undercount(ev: Evidence, timing: Timing | None = None) -> str | None:
    """A controller that uses events drove the camera, the light moved towards the saturation since
    P-TEDI's anchor (the frame's estimate of ln P(s) is beyond the anchor in direction ``d``),
    P-TEDI's predicted change falls short of the frame's by at least :data:`UNDERCOUNT_LN`, and the
    events lost at the sensor's bus ceiling over that time carried at least :data:`LOST_EXPLAINS`
    of the shortfall (``lost_change``, from the simulator's count; unknown: the rule does not hold)."""
    if not ev.sees_events or ev.drives is False:
        return None
    p, f = ev.predicted_change, ev.frame_change
    if not (math.isfinite(p) and math.isfinite(f)):
        return None
    d = ev.direction
    other = ev.under if d > 0 else ev.over
    if other > ONE_SIDED or d * f <= 0 or d * (f - p) < UNDERCOUNT_LN:
        return None
    lost = ev.lost_change
    short = d * (f - p)
    if not math.isfinite(lost) or d * lost < LOST_EXPLAINS * short:
        return None
    bound = "at least " if d > 0 else "at most "
    return (
        f"P-TEDI predicted a change of {_ln(p)} since its anchor, the frame shows "
        f"{bound}{_ln(f)} (it missed at least {short:.2f} ln of the change); the events the sensor lost at "
        f"its bus ceiling in that time carried {_ln(lost)}"
    )


def rule_controller_lag(ev: Evidence, timing: Timing | None) -> str | None:
    """The controller waited for a frame: it had not moved the setting towards the change since its
    previous frame, no correcting command came between the change and the last
    moment one could take effect on this exposure (start minus latency), its first correcting command
    came only once the first frame exposed after the change had ended, and that frame was read out
    after that moment (ground truth: the onset from the lighting trace, the lane's commands and
    frames, the readout time). The same rule for every controller, from measured command timing:
    an event-driven controller that reacted to the events is not lagging, one that waited for the
    frame is. Without ground truth: the previous frame was not saturated this way and the controller
    issued no correcting command between its end and that moment."""
    if ev.drives is False:
        return None
    s = ev.start_us
    lat = ev.latency_us or 0.0
    deadline = s - lat
    fixes = [c for c in ev.commands if _correcting(ev, c)]
    if ev.recent_frames:
        step = math.log(ev.exposure_us * ev.gain) - math.log(ev.recent_frames[-1][2])
        if -ev.direction * step >= CORRECTION_LN:
            return None  # it had already moved the setting the right way since its last frame: too little, not late
    if timing is not None and timing.source == "ground truth":
        on = timing.onset_us
        if on is None or on > deadline:
            return None
        after = [c for c in fixes if c.issue_us >= on]
        if any(c.issue_us <= deadline for c in after):
            return None  # it corrected in time: whatever saturated the frame, it was not a wait for a frame
        readout = ev.truth.readout_us if ev.truth is not None else 0.0
        shown = [f for f in ev.recent_frames if f[1] > on]
        first_end = shown[0][1] if shown else ev.end_us  # the first frame exposed (in part) after the change
        if first_end + readout <= deadline:
            return None  # a frame showing the change was there in time: not a frame's lag
        if after and after[0].issue_us < first_end:
            return None  # it reacted before any frame could show the change (from events), only too little
        first = (
            f"its first correcting command came {_ms(after[0].issue_us - on)} after the change, once "
            "a frame exposed after it had ended"
            if after
            else "it issued no correcting command before this frame"
        )
        return (
            f"the light {_light(ev)} {_ms(s - on)} before the exposure started "
            f"({timing.label or 'a lighting change'}); {first}, and the first such frame was read out "
            f"{_ms(first_end + readout - deadline)} after the last moment a command could still take effect "
            f"on this exposure (commands take effect {_ms(lat)} after they are issued)"
        )
    if ev.previous_saturated is False and ev.recent_frames:
        prev_end = ev.recent_frames[-1][1]
        if any(prev_end <= c.issue_us <= deadline for c in fixes):
            return None
        return (
            "the previous frame was not saturated and the controller issued no correcting command between "
            "its end and the last moment one could take effect on this exposure: it learnt of the change "
            "one frame late"
        )
    return None


def rule_controller(ev: Evidence, timing: Timing | None) -> str:
    """The residual: the controller's own choice with what it knew (always holds)."""
    parts = [
        f"{ev.over if ev.direction > 0 else ev.under:.0%} {ev.kind}-exposed at {ev.exposure_us:.0f} µs × {ev.gain:.3g}"
    ]
    if ev.drives is False:
        parts.append("open loop: the recorded camera's own exposure control chose this setting")
    other = ev.under if ev.direction > 0 else ev.over
    if other > ONE_SIDED:
        parts.append(f"clipped at both ends ({ev.over:.0%} over, {ev.under:.0%} under)")
    if ev.truth is not None:
        parts.append(f"the best single exposure would record {best_valid_fraction(ev.truth):.0%} of the pixels valid")
    if timing is not None and timing.source == "ground truth":
        if timing.state == "throughout":
            parts.append("the light had saturated this setting for longer than the trace's look-back")
        elif timing.state == "not_reached":
            parts.append(
                "the scene's mean light never reached this setting's saturating level (the scene's "
                "pattern, not its level, clipped the frame)"
            )
        else:
            assert timing.onset_us is not None  # crossing_time gives "crossed" with its onset
            parts.append(
                f"the light crossed the level this setting holds {_ms(ev.start_us - timing.onset_us)} "
                "before the exposure started"
            )
    if ev.recent_frames and ev.drives is not False:
        step = math.log(ev.exposure_us * ev.gain) - math.log(ev.recent_frames[-1][2])
        if -ev.direction * step >= CORRECTION_LN:
            parts.append(f"converging: the exposure-gain product moved ×{math.exp(step):.2f} since the previous frame")
    p, f = ev.predicted_change, ev.frame_change
    if math.isfinite(p) and math.isfinite(f) and ev.sees_events and other <= ONE_SIDED:
        parts.append(f"P-TEDI predicted {_ln(p)}, the frame shows {_ln(f)} since the anchor")
        if math.isfinite(ev.lost_change):
            parts.append(f"events lost at the bus ceiling since then carried {_ln(ev.lost_change)}")
    if ev.drives is not False and ev.commands:
        c = ev.commands[-1]
        parts.append(f"last command {c.exposure_us:.0f} µs × {c.gain:.3g} at {_ms(c.issue_us - ev.start_us)}")
    elif ev.drives is not False and ev.sees_events is not None:
        parts.append("no command from the controller")
    return "; ".join(parts)


RULES = (
    ("change_during_exposure", rule_change_during_exposure),
    ("command_latency", rule_command_latency),
    ("limit_reached", rule_limit_reached),
    ("prediction_undercount", rule_prediction_undercount),
    ("controller_lag", rule_controller_lag),
    ("controller", rule_controller),
)


def diagnose(ev: Evidence) -> tuple[str, str]:
    """``(cause, explanation)`` of a saturated frame: the first rule of :data:`RULES` that holds."""
    timing = truth_timing(ev)
    for name, rule in RULES:
        msg = rule(ev, timing)
        if msg is not None:
            return name, msg
    raise AssertionError("rule_controller always holds")  # pragma: no cover


__all__ = [
    "AT_LIMIT",
    "CAUSES",
    "CORRECTION_LN",
    "Command",
    "EXPOSURE_CHANGE_LN",
    "Evidence",
    "LOST_EXPLAINS",
    "ONE_SIDED",
    "RULES",
    "Timing",
    "UNDERCOUNT_LN",
    "best_valid_fraction",
    "crossing_time",
    "diagnose",
    "rule_change_during_exposure",
    "rule_command_latency",
    "rule_controller",
    "rule_controller_lag",
    "rule_limit_reached",
    "rule_prediction_undercount",
    "saturating_level",
    "truth_timing",
]
