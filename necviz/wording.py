"""Summary lines in words: a run's summary, saturated frames and their diagnosed causes as a newcomer reads them.

``1 frame over 50 % clipped (frame 100)`` rather than ``saturated frames (>50 %): 1: 100``; the
causes of :mod:`necviz.core.diagnosis` by what they mean rather than by their JSON keys; a lane's
reaction in sensor time (:mod:`necviz.reaction`) in one line; whether a paced run kept its speed; and
:func:`print_summary`, the summary every dashboard run prints from its statistics.
"""

from __future__ import annotations

from necviz.progress import plural

#: What each diagnosed cause (necviz.core.diagnosis.CAUSES) means, in the order the rules apply.
CAUSE_WORDS = {
    "change_during_exposure": "the light changed during the exposure",
    "command_latency": "the light changed too shortly before the exposure for any command to act",
    "limit_reached": "the exposure and gain were already at their limit",
    "prediction_undercount": "P-TEDI's prediction missed events the sensor dropped at its bus ceiling",
    "controller_lag": "the controller waited for a frame to react",
    "controller": "the controller's own choice",
}


def saturated_frames(sequences, shown: int = 12) -> str:
    """``1 frame over 50 % clipped (frame 100)``; ``3 frames ... (frames 4, 9, 12)``; the first ``shown`` listed."""
    seqs = list(sequences)
    listed = ", ".join(map(str, seqs[:shown])) + (f" and {len(seqs) - shown} more" if len(seqs) > shown else "")
    return f"{plural(len(seqs), 'frame')} over 50 % clipped ({'frame' if len(seqs) == 1 else 'frames'} {listed})"


def diagnosed_causes(counts: dict) -> str | None:
    """``why: the controller's own choice (1 frame)``; causes by frequency; None when none was diagnosed."""
    items = sorted(((k, v) for k, v in counts.items() if v), key=lambda kv: -kv[1])
    if not items:
        return None
    return "why: " + "; ".join(f"{CAUSE_WORDS.get(k, k.replace('_', ' '))} ({plural(v, 'frame')})" for k, v in items)


def reaction_line(r: dict | None) -> str:
    """A lane's reaction in sensor time (its ``"reaction"`` summary, :class:`~necviz.reaction.ReactionMeter`), one
    line; '' when nothing was measured."""
    if r and r.get("open_loop") and not r.get("changes"):
        return (
            f"reaction: open loop ({r['commands']} commands computed; the recorded frames do not follow them, "
            "so no reaction is measured)"
        )
    if not r or not r.get("changes"):
        return ""
    late, lag = r["frames_late"], r["command_to_exposure_us"]
    if not r["applied"]:
        return (
            f"reaction: none of {r['changes']} exposure changes reached a frame (open loop, or the run was too short)"
        )

    def ms(v):
        return "—" if v is None else f"{v / 1000:.1f} ms"

    return (
        f"reaction (sensor time): {r['applied']} of {r['changes']} changes reached a frame "
        f"({r['superseded']} superseded); frames late p50 {late['p50']:.0f} p99 {late['p99']:.0f} max {late['max']}; "
        f"cause to exposure p50 {ms(lag['p50'])} p99 {ms(lag['p99'])}"
    )


#: Below this fraction of the asked speed a run is said to have fallen behind.
BEHIND = 0.9


def pace_note(asked: float | None, achieved: float | None) -> str | None:
    """``"ran at 0.63x real time: latency and recovery are not real-time figures"`` when a paced run
    (``asked``: its speed, None = as fast as possible) went at ``achieved`` (sensor seconds per wall second,
    None = unknown) below :data:`BEHIND` of it; else None."""
    if asked is None or achieved is None or achieved >= BEHIND * asked:
        return None
    if asked == 1:
        return f"ran at {achieved:.2f}x real time: latency and recovery are not real-time figures"
    return f"ran at {achieved:.2f}x real time, not the {asked:g}x asked: latency and recovery are not paced figures"


def print_summary(out, stats: dict) -> None:
    """A run's summary (:meth:`~necviz.pipeline.Pipeline.finish`'s, with what the session adds: ``source``,
    ``speed``, ``achieved_speed``) in words on ``out`` (None: nothing): the stream, a row per lane and its
    reaction, the camera, clips, video and viewer, and a note when a paced run fell behind (:func:`pace_note`)."""
    if out is None:
        return
    print(
        f"  {plural(stats['events'], 'event')}, {plural(stats['frames'], 'frame')} over {stats['duration_s']:.2f} s "
        f"({stats['event_rate_mev_s']:.2f} Mev/s) in {stats['wall_s']:.1f} s wall",
        file=out,
    )
    w = max([8, *(len(n) for n in stats["lanes"])])  # nec-frames, user-registered names: every row aligned
    for name, s in stats["lanes"].items():
        print(
            f"  {name:{w}s} {plural(s['frames'], 'frame'):>11s}, {s['saturated_frames_50']:3d} saturated, "
            f"{plural(s['commands'], 'command'):>14s}, processing p50 {_us(s['latency_p50_us'])} "
            f"p99 {_us(s['latency_p99_us'])}"
            + (f", P-TEDI c_on {s['ptedi']['c_on']:.4g} c_off {s['ptedi']['c_off']:.4g}" if "ptedi" in s else ""),
            file=out,
        )
        line = reaction_line(s.get("reaction"))
        if line:
            print(f"  {'':8s} {line}", file=out)
    src = stats.get("source")
    if src:
        lost = src.get("dropped_events", 0)
        print(
            f"  camera: {plural(lost, 'event')} dropped by the device"
            + (" (its FIFO overflowed while the host was not reading, or its bus was saturated)" if lost else "")
            + f"; {plural(src.get('skipped_words', 0), 'stream word')} skipped; "
            f"{plural(src.get('reconnects', 0), 'reconnect')}",
            file=out,
        )
        if "lag_peak_us" in src:
            held = src.get("backpressure_events", 0)
            print(
                f"  reader: backlog peak {src['lag_peak_us'] / 1000:.1f} ms of sensor time; "
                + (
                    f"held back {held} times for {src.get('backpressure_s', 0.0):.2f} s (the host fell behind: "
                    "the device dropped meanwhile)"
                    if held
                    else "never held back"
                ),
                file=out,
            )
    fr = stats.get("flight_recorder")
    if fr:
        dropped = (
            f"; the {fr['buffer_bytes'] / 2**20:.0f} MB budget dropped {fr['dropped_events']:,} events "
            "(clips hold less than --clip-before)"
            if fr["dropped_events"]
            else ""
        )
        lost = f", {fr['clips_dropped']} dropped (writer behind)" if fr["clips_dropped"] else ""
        errors = f", {fr['write_errors']} failed to write" if fr["write_errors"] else ""
        print(
            f"  clips: {fr['clips_written']} written ({plural(fr['failures'], 'saturated frame')}, "
            f"{plural(fr['marks'], 'mark')}){lost}{errors}; peak held {fr['peak_bytes'] / 2**20:.1f} MB{dropped}",
            file=out,
        )
    vd = stats.get("video")
    if vd:
        print(
            f"  video: {vd['path']} ({plural(vd['frames'], 'frame')}, {vd['duration_s']:.2f} s at x{vd['speed']:g}, "
            f"{vd['width']}x{vd['height']})",
            file=out,
        )
    sk = stats.get("sink")
    if sk:
        print(
            f"  viewer: {plural(sk['frames_logged'], 'frame')}, {plural(sk['event_images'], 'event image')}; dropped "
            f"{plural(sk['frames_dropped'], 'frame')} and {plural(sk['event_batches_dropped'], 'event batch', 'event batches')}; "
            f"{sk['events_decimated']:,} of {plural(sk['events_seen'], 'event')} not drawn (decimation)",
            file=out,
        )
    behind = pace_note(stats.get("speed"), stats.get("achieved_speed"))
    if behind:
        print(f"  {behind}", file=out)


def _us(v: float) -> str:
    return "—" if v != v else f"{v:.0f} µs"


__all__ = [
    "BEHIND",
    "CAUSE_WORDS",
    "diagnosed_causes",
    "pace_note",
    "print_summary",
    "reaction_line",
    "saturated_frames",
]
