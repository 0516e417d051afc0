"""The flight recorder: bounded memory whatever the rate, a clip around every failure (merged when they
overlap), nothing written without one, clips that replay at the failure; and ``mark`` at the prompt."""

from __future__ import annotations

import io
import math
import re

import numpy as np
import pytest
from rrd_read import Rrd

from necviz.core.control import ExposureCommand
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry
from necviz.dashboard.flight_recorder import FlightRecorder, cause_slug
from necviz.drivers.recordings import open_recording
from necviz.options import ClipOptions
from necviz.telemetry import FrameRecord

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SENSOR = SensorGeometry(32, 24, "tiny")
BATCH_US = 1000


def _recorder(folder, lanes=None, **kw) -> FlightRecorder:
    clip = ClipOptions(folder, **{"before_s": 0.5, "after_s": 0.3, **kw})
    lanes = lanes or {"a": "cam"}
    return FlightRecorder(clip, sensor=SENSOR, lanes=lanes, drivers={c: n for n, c in lanes.items()}, layout="live")


def _batch(t0: int, n: int) -> np.ndarray:
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = t0 + np.arange(n) * BATCH_US // max(n, 1)
    ev["x"], ev["y"] = np.arange(n) % 32, np.arange(n) % 24
    ev["p"] = 1
    return ev


def _record(seq, s, e, over) -> FrameRecord:
    return FrameRecord(
        seq, s, e, float(e - s), 1.0, over, 0.0, saturation_cause="command_latency" if over > 0.5 else ""
    )


def _run(fr: FlightRecorder, seconds: float, per_batch: int, saturated_at=(), frame_period_us=20_000, lanes=None):
    """Feed ``seconds`` of 1 ms event batches and a frame every 20 ms per lane; frames starting at the
    times in ``saturated_at`` (µs; ``(lane, µs)`` pairs for several lanes) are saturated."""
    lanes = lanes or {"a": "cam"}
    sat = {(x if isinstance(x, tuple) else ("a", x)) for x in saturated_at}
    fr.started(0, {})
    seq = 0
    for k in range(int(seconds * 1e6) // BATCH_US):
        t = k * BATCH_US
        if t % frame_period_us == 0:  # stream order: a marker before the events at/after its time
            for cam in lanes.values():
                fr.packet(cam, ExposureMarker(t, "start"))
        fr.events(_batch(t, per_batch))
        if t % frame_period_us == 4_000:
            s, e = t - 4_000, t + BATCH_US
            for lane, cam in lanes.items():
                fr.packet(cam, ExposureMarker(e, "end"))
                f = Frame(np.full((24, 32), 7 + len(lane), np.uint8), s, e, 1.0, seq)
                fr.packet(cam, f)
                fr.frame(lane, f, _record(seq, s, e, 0.9 if (lane, s) in sat else 0.0))
                fr.command(lane, ExposureCommand(1000.0, 1.0, t), 5.0)
                fr.prediction(lane, t, 1.0)
            seq += 1
    return fr.close()


def test_a_run_without_failures_writes_nothing_and_memory_follows_the_window(tmp_path):
    fr = _recorder(tmp_path, before_s=0.2)
    stats = _run(fr, 2.0, 100)
    assert list(tmp_path.iterdir()) == []
    assert stats["clips_written"] == 0 and stats["dropped_events"] == 0
    # 0.2 s (+ the 0.2 s slack for an exposure seen at its end) of 100-event batches (13 bytes an event),
    # frames and small entries: a fifth of the 2 s fed
    from necviz.dashboard.flight_recorder import SLACK_US

    per_second = 1000 * 100 * 13 + 50 * (32 * 24 + 160) + 50 * 3 * 160
    window = 0.2 + SLACK_US / 1e6
    assert per_second * window * 0.95 <= stats["peak_bytes"] <= per_second * window * 1.05


def test_the_budget_bounds_memory_whatever_the_rate_and_says_so(tmp_path):
    budget = 1 << 20
    fr = _recorder(tmp_path, before_s=5.0, memory_mb=budget / 2**20)
    stats = _run(fr, 1.0, 2000, saturated_at=(600_000,))  # 26 MB/s of events against a 1 MB budget
    assert stats["dropped_events"] > 0
    # everything held (ring, clips, the clip being written), each item once, within the data budget:
    # the budget less the writer's share
    assert fr.data_budget == budget - budget // 4
    assert stats["peak_bytes"] <= fr.data_budget + 2000 * 13 + 4096  # (the item that tipped it over)
    assert stats["clips_written"] >= 1
    rec = open_recording(sorted(tmp_path.glob("*.necrec"))[0])
    n = sum(len(p) for p in rec if isinstance(p, EventBatch))
    assert 0 < n * 13 <= fr.data_budget  # what the clip holds is what fitted in the budget
    # and it says it covers less than --clip-before asked for
    assert int(rec.properties["clip_window_start_us"]) > int(rec.properties["clip_requested_start_us"])


def test_a_clip_covers_before_and_after_the_failure_and_opens_at_it(tmp_path, capsys):
    fr = _recorder(tmp_path)
    stats = _run(fr, 2.0, 50, saturated_at=(1_000_000,))
    assert stats["clips_written"] == 1 and stats["failures"] == 1
    necrec = sorted(tmp_path.glob("*.necrec"))
    rrd = sorted(tmp_path.glob("*.rrd"))
    assert len(necrec) == 1 and len(rrd) == 1 and necrec[0].stem == rrd[0].stem + "-a-command_latency"
    assert rrd[0].stem.endswith("-t1.000s")
    rec = open_recording(necrec[0])
    packets = list(rec)
    t = np.concatenate([p.events["t"] for p in packets if isinstance(p, EventBatch)])
    # the ring kept 0.5 s before the failure (frame start 1.0 s); the clip ran 0.3 s after it
    assert 500_000 - BATCH_US <= t[0] <= 500_000 + BATCH_US
    assert 1_300_000 - BATCH_US <= t[-1] <= 1_300_000 + 2 * BATCH_US
    frames = [p for p in packets if isinstance(p, Frame)]
    assert all(f.image.shape == (24, 32) for f in frames) and len(frames) >= 35
    assert rec.properties["clip_cause"] == "command_latency" and rec.properties["clip_failure_us"] == 1_000_000
    assert len(rec.commands) == len(frames) or abs(len(rec.commands) - len(frames)) <= 1
    # the .rrd: what the dashboard showed over the clip (frames, events, series), and the window it declares
    view = Rrd(rrd[0])
    assert any(e.startswith("a/") for e in view.components) and "events" in " ".join(view.components)
    from rerun.chunk import RrdReader

    assert RrdReader(str(rrd[0])).blueprints()  # the layout, looping over the window, is in the file
    lo, hi = float(view.property("run", "clip_focus_start_s")), float(view.property("run", "clip_focus_end_s"))
    assert t[0] / 1e6 - 0.002 <= lo <= 0.5 + 0.002 and hi == pytest.approx(t[-1] / 1e6, abs=0.003)
    # replay of the clip loops over that same window, on the same time axis, never before its data
    from necviz import ReplayOptions, ViewerOptions, run_replay

    run_replay(ReplayOptions(necrec[0]), ViewerOptions(save=tmp_path / "replay.rrd"))
    said = capsys.readouterr().out
    m = re.search(r"clip: command_latency at (\S+) s; the viewer loops over (\S+)\.\.(\S+) s", said)
    assert (
        m
        and float(m.group(1)) == pytest.approx(1.0)
        and (float(m.group(2)), float(m.group(3)))
        == (
            pytest.approx(lo, abs=1e-3),
            pytest.approx(hi, abs=1e-3),
        )
    )


def test_overlapping_failures_merge_and_distant_ones_do_not(tmp_path):
    fr = _recorder(tmp_path)
    # 1.0 and 1.2 overlap; 1.7's window [1.2, 2.0] overlaps [0.5, 1.5] only by its --clip-before: one
    # clip all the same (the next clip would otherwise start where the last ended); 2.6 is apart
    stats = _run(fr, 3.5, 10, saturated_at=(1_000_000, 1_200_000, 1_700_000, 2_700_000))
    assert stats["failures"] == 4 and stats["clips_written"] == 2
    names = sorted(p.stem for p in tmp_path.glob("*.necrec"))
    assert [n.split("-t")[1] for n in names] == ["1.000s-a-command_latency", "2.700s-a-command_latency"]
    first = open_recording(tmp_path / f"{names[0]}.necrec")
    assert int(first.properties["clip_failures"]) == 3
    ts = [p.t_last_us for p in first if isinstance(p, EventBatch)]
    assert min(ts) <= 500_000 + BATCH_US and max(ts) >= 2_000_000 - BATCH_US  # one window, 0.5 .. 2.0 s
    second = open_recording(tmp_path / f"{names[1]}.necrec")
    t0 = min(p.events["t"][0] for p in second if isinstance(p, EventBatch))
    assert 2_200_000 - BATCH_US <= t0 <= 2_200_000 + BATCH_US  # a whole --clip-before


def test_every_failing_lane_is_in_the_clip_with_its_own_camera(tmp_path):
    lanes = {"nec": "cam-nec", "fixed": "cam-fixed"}
    fr = _recorder(tmp_path, lanes=lanes)
    stats = _run(
        fr, 2.0, 10, saturated_at=(("nec", 1_000_000), ("fixed", 1_100_000), ("fixed", 1_200_000)), lanes=lanes
    )
    assert stats["clips_written"] == 1 and stats["failures"] == 3
    necrec = {p.stem.split("-")[-2]: p for p in tmp_path.glob("*.necrec")}
    assert set(necrec) == {"nec", "fixed"} and len(list(tmp_path.glob("*.rrd"))) == 1
    for lane, n_failures, first in (("nec", 1, 1_000_000), ("fixed", 2, 1_100_000)):
        rec = open_recording(necrec[lane])
        assert rec.properties["clip_lane"] == lane and rec.properties["clip_camera"] == lanes[lane]
        assert int(rec.properties["clip_failures"]) == n_failures and int(rec.properties["clip_failure_us"]) == first
        frames = [p for p in rec if isinstance(p, Frame)]
        assert frames and all(int(f.image[0, 0]) == 7 + len(lane) for f in frames)  # that lane's camera only


def test_mark_says_what_it_will_do(tmp_path):
    fr = _recorder(tmp_path)
    fr.started(0, {})
    fr.events(_batch(0, 5))
    reply = fr.mark("here")
    assert "0.5 s before and 0.3 s after" in reply and "0.8 s of sensor time from now at the earliest" in reply
    fr.close()


def test_cause_names_are_file_name_safe():
    assert cause_slug("command_latency") == "command_latency"
    assert cause_slug("") == "saturated" and cause_slug("a b/c") == "a-b-c"


def test_mark_at_the_prompt_writes_a_clip_in_a_demo(tmp_path):
    from necviz import ClipOptions, DemoOptions, SceneOptions, TuneOptions, ViewerOptions, run_demo

    clips = tmp_path / "clips"
    clips.mkdir()
    out = io.StringIO()
    stats = run_demo(
        DemoOptions(
            SceneOptions("static_lab", duration_s=0.6),
            ("nec",),
            tune=TuneOptions(prompt=True),
            clips=ClipOptions(clips, before_s=0.2, after_s=0.1),
        ),
        ViewerOptions(save=tmp_path / "demo.rrd"),
        out=out,
        stdin=io.StringIO("mark look here\n"),
    )
    fr = stats["flight_recorder"]
    assert fr["marks"] == 1
    marked = [p for p in clips.glob("*.necrec") if p.stem.endswith("-mark")]
    assert len(marked) == 1, sorted(p.name for p in clips.iterdir())
    rec = open_recording(marked[0])
    assert any(d.get("mark", {}).get("text") == "look here" for _, d in rec.annotations)
    assert "clips: " in out.getvalue()


def test_clip_options_are_checked_before_anything_runs(tmp_path):
    from necviz.commands.cli import main

    (tmp_path / "a-file").write_text("x")
    assert main(["demo", "--clips", str(tmp_path / "a-file"), "--save", str(tmp_path / "x.rrd")]) == 2
    assert not (tmp_path / "x.rrd").exists()
    from necviz import ClipOptions
    from necviz.flags import in_flag_terms

    with pytest.raises(Exception, match="before_s") as info:  # the library names the field
        ClipOptions(tmp_path, before_s=-1)
    assert "--clip-before" in in_flag_terms(info.value)  # the command line, the flag
    assert math.isfinite(5.0)


def test_a_clip_shows_the_lane_by_its_controller(tmp_path):
    """A live lane (entity root ``camera``) is shown in its clip as in the session: curves named by its
    controller (the session passes :func:`~necviz.dashboard.session.lane_labels`)."""
    from necviz import schema as S

    fr = _recorder(tmp_path)
    fr.labels = {"a": "nec"}
    assert _run(fr, 1.5, 50, saturated_at=(1_000_000,))["clips_written"] == 1
    view = Rrd(sorted(tmp_path.glob("*.rrd"))[0])
    assert view.static_values("a/" + S.EXPOSURE_APPLIED, "SeriesLines:names") == ["nec applied"]
