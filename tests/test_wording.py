"""Summary lines a newcomer can read: counts with their singular, causes in words."""

from __future__ import annotations

import io
import re

from necviz.core.diagnosis import CAUSES
from necviz.wording import CAUSE_WORDS, diagnosed_causes, print_summary, saturated_frames


def test_saturated_frames_in_words():
    assert saturated_frames([100]) == "1 frame over 50 % clipped (frame 100)"
    assert saturated_frames([4, 9]) == "2 frames over 50 % clipped (frames 4, 9)"
    assert saturated_frames(range(20), shown=3) == "20 frames over 50 % clipped (frames 0, 1, 2 and 17 more)"


def test_every_diagnosed_cause_has_words():
    assert set(CAUSE_WORDS) == set(CAUSES)
    assert diagnosed_causes({"controller": 1}) == "why: the controller's own choice (1 frame)"
    text = diagnosed_causes({"controller": 1, "change_during_exposure": 3, "limit_reached": 0})
    assert text == "why: the light changed during the exposure (3 frames); the controller's own choice (1 frame)"
    assert diagnosed_causes({"controller": 0}) is None


def test_the_run_summary_says_1_frame_not_1_frames():
    lane = {"frames": 1, "saturated_frames_50": 1, "commands": 1, "latency_p50_us": 80.0, "latency_p99_us": 90.0}
    stats = {
        "events": 1,
        "frames": 1,
        "duration_s": 0.02,
        "event_rate_mev_s": 0.0,
        "wall_s": 0.1,
        "lanes": {"nec": lane},
        "source": {"dropped_events": 1, "skipped_words": 1, "reconnects": 1},
        "video": {"path": "v.mp4", "frames": 1, "duration_s": 0.03, "speed": 1.0, "width": 8, "height": 8},
        "sink": {
            "frames_logged": 1,
            "event_images": 1,
            "frames_dropped": 1,
            "event_batches_dropped": 1,
            "events_decimated": 0,
            "events_seen": 1,
        },
    }
    out = io.StringIO()
    print_summary(out, stats)
    text = out.getvalue()
    assert not re.search(r"\b1 (frames|events|commands|event images|event batches|reconnects|stream words)\b", text), (
        text
    )
    assert "1 frame," in text and "1 command," in text and "1 event batch;" in text


def test_lane_rows_line_up_whatever_the_names():
    lane = {"frames": 40, "saturated_frames_50": 2, "commands": 12, "latency_p50_us": 80.0, "latency_p99_us": 90.0}
    stats = {"events": 10, "frames": 80, "duration_s": 0.8, "event_rate_mev_s": 0.0, "wall_s": 1.0}
    stats["lanes"] = {"nec": lane, "nec-frames": lane, "navid-tuned": lane}
    out = io.StringIO()
    print_summary(out, stats)
    rows = [ln for ln in out.getvalue().splitlines() if "processing p50" in ln]
    assert len(rows) == 3 and len({r.index(" frames,") for r in rows}) == 1, rows
