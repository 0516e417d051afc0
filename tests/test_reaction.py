"""The reaction in sensor time (necviz.reaction): frames late and cause-to-exposure time, counted by hand."""

from necviz.core.control.controller import CameraLimits
from necviz.reaction import ReactionMeter


def test_frames_late_counts_the_exposures_started_between_cause_and_use():
    m = ReactionMeter()
    for s in (0, 20_000):
        m.start(s)
    m.command(25_000, 3000.0, 1.0)  # caused at 25 ms: the exposure at 40 ms is the next one
    m.start(40_000)
    m.frame(40_000, 5000, 1.0)  # still the old setting: not this command
    m.start(60_000)
    m.frame(60_000, 3000, 1.0)  # used by the exposure at 60 ms: one exposure (40 ms) started in between
    m.command(61_000, 2000.0, 1.0)
    m.command(62_000, 2000.0, 1.0)  # the same setting again: no new change
    m.command(63_000, 1000.0, 1.0)  # replaces 2000 before any frame used it
    m.start(80_000)
    m.frame(80_000, 1000, 1.0)  # the very next exposure
    r = m.summary()
    assert (r["commands"], r["changes"], r["applied"], r["superseded"]) == (4, 3, 2, 1)
    assert m.late_counts == {1: 1, 0: 1}
    assert r["frames_late"]["max"] == 1 and r["frames_late"]["p50"] == 0
    lo, hi = r["command_to_exposure_us"]["p50"], r["command_to_exposure_us"]["max"]
    assert abs(lo - 17_000) < 0.01 * 17_000 and hi == 35_000  # 80 - 63 ms and 60 - 25 ms


def test_commands_are_matched_as_the_camera_clamps_them():
    m = ReactionMeter(CameraLimits(exposure_min_us=10.0, exposure_max_us=19_000.0, gain_max=4.0))
    m.command(100, 50_000.0, 8.0)  # clamped to 19 ms and gain 4 by the camera
    m.frame(20_000, 19_000, 4.0)
    assert m.applied == 1 and m.late_counts == {0: 1}


def test_an_open_loop_frame_that_never_follows_leaves_the_change_pending():
    m = ReactionMeter()
    m.command(0, 1234.0, 1.0)
    for k in range(5):
        m.frame(20_000 * (k + 1), 5000, 1.0)
    r = m.summary()
    assert r["applied"] == 0 and r["pending"] == 1 and r["frames_late"]["p99"] is None


def test_an_open_loop_lane_counts_its_commands_and_says_so():
    from necviz.wording import reaction_line

    m = ReactionMeter()
    m.command(0, 1234.0, 1.0, applies=False)
    m.frame(20_000, 1234, 1.0)  # a recorded frame that happens to match: not a reaction
    r = m.summary()
    assert r["open_loop"] and r["commands"] == 1 and r["applied"] == 0
    assert "open loop" in reaction_line(r)
