"""Summary lines in words: saturated frames and their diagnosed causes as a newcomer reads them.

``1 frame over 50 % clipped (frame 100)`` rather than ``saturated frames (>50 %): 1: 100``; the
causes of :mod:`necviz.core.diagnosis` by what they mean rather than by their JSON keys.
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


__all__ = ["CAUSE_WORDS", "diagnosed_causes", "saturated_frames"]
