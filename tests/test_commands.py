"""The dashboard commands end to end on the emulated camera and the real sample recording."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SHARED_DATA
from rrd_read import Rrd

from necviz import schema as S
from necviz.commands.cli import main
from necviz.core.frames import Frame
from necviz.drivers.recordings import open_recording
from necviz.drivers.source import CameraInfo

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SAMPLE = SHARED_DATA / "davis346_sample.aedat4"
needs_sample = pytest.mark.skipif(not SAMPLE.exists(), reason=f"real recording {SAMPLE} not available")


def test_live_emulated_closes_the_loop_and_records(tmp_path, capsys):
    rrd, rec = tmp_path / "live.rrd", tmp_path / "live.necrec"
    code = main(
        ["live", "--device", "emulated", "--duration", "0.6", "--save", str(rrd), "--record", str(rec), "--no-prompt"]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "nec drives the exposure" in out
    r = Rrd(rrd)
    for leaf in S.LANE_ENTITIES:
        assert r.rows.get(S.path("camera", leaf), 0) > 0, leaf
    recording = open_recording(rec)
    frames = [p for p in recording if isinstance(p, Frame)]
    # the recorder keeps every frame; the live view may skip some (60 per wall second at most)
    assert len(frames) >= 20 and 0 < r.rows["camera/frame"] <= len(frames)
    _, exposure_logged = r.series("camera/exposure/applied")
    assert len(exposure_logged) == len(frames)  # scalar series are never dropped
    assert len(recording.commands) > 1  # initial setting + NEC's commands, as the camera got them
    exposures = {f.exposure_us for f in frames}
    assert len(exposures) > 1  # the commands reached the (emulated) exposure register


def test_unplugged_camera_flushes_everything_and_exits_nonzero(tmp_path):
    """Run as a user would: a separate process, an unplug mid-stream, then both files read back."""
    rrd, rec = tmp_path / "u.rrd", tmp_path / "u.necrec"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "necviz",
            "live",
            "--device",
            "emulated",
            "--duration",
            "3",
            "--emulate-unplug",
            "0.4",
            "--save",
            str(rrd),
            "--record",
            str(rec),
            "--no-prompt",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert "necviz: error: DAVIS346 EMU00346 was unplugged at t=0.4" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert "recording so far" in proc.stdout
    exe = Path(sys.executable).with_name("rerun")
    if exe.exists():
        assert subprocess.run([str(exe), "rrd", "verify", str(rrd)], capture_output=True).returncode == 0
    frames = [p for p in open_recording(rec) if isinstance(p, Frame)]
    assert 15 <= len(frames) <= 21 and frames[-1].exposure_end_us <= 410_000
    r = Rrd(rrd)
    assert 0 < r.rows["camera/frame"] <= len(frames)  # the live view may skip frames; the series may not
    assert len(r.series("camera/exposure/applied")[1]) == len(frames)


def test_a_live_session_may_outlast_any_simulated_scene(tmp_path, capsys):
    """``--duration`` of ``live`` is the session's length (hours for a soak), not the scene's (<= 600 s):
    a one-hour emulated session starts; the emulated unplug ends it at once."""
    code = main(
        [
            "live",
            "--device",
            "emulated",
            "--duration",
            "3600",
            "--emulate-unplug",
            "0.1",
            "--save",
            str(tmp_path / "l.rrd"),
            "--no-prompt",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "unplugged" in err and "out of range" not in err


def test_no_camera_is_a_clear_error(capsys):
    if os.path.exists("/dev/bus/usb"):
        pytest.skip("a USB bus is present; a camera might be attached")
    assert main(["live", "--device", "usb", "--no-prompt", "--save", "x.rrd"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("necviz: error: no DAVIS camera found") and "lsusb" in err and "152a" in err


def test_devices_lists_the_emulated_camera(capsys):
    main(["devices"])
    out = capsys.readouterr().out
    assert "EMU00346" in out and "emulated" in out


@needs_sample
def test_replay_real_sample_reports_prediction_error(tmp_path, capsys):
    js = tmp_path / "r.json"
    assert main(["replay", str(SAMPLE), "--save", str(tmp_path / "r.rrd"), "--json", str(js)]) == 0
    s = json.loads(js.read_text())
    assert s["frames"] == 4 and s["events"] == 6676
    assert 0.17 < s["duration_s"] < 0.18
    assert s["saturated_frames_50"] == sum(d["saturated"] for d in s["frames_detail"])
    # three frames follow an anchored one: each has a prediction; P-TEDI agrees with them closely
    assert s["prediction_error_frames"] == 3 and s["prediction_error_rmse"] < 0.1
    assert all(d["exposure_us"] == 500 for d in s["frames_detail"])
    r = Rrd(tmp_path / "r.rrd")
    t, _ = r.series("camera/exposure/applied")
    assert len(t) == 4 and 0 <= t[0] < 0.2  # the timeline starts at the recording's first timestamp


@needs_sample
def test_replay_start_end_restrict_the_range(tmp_path):
    js = tmp_path / "r.json"
    assert (
        main(
            [
                "replay",
                str(SAMPLE),
                "--start",
                "0.05",
                "--end",
                "0.12",
                "--save",
                str(tmp_path / "r.rrd"),
                "--json",
                str(js),
            ]
        )
        == 0
    )
    s = json.loads(js.read_text())
    assert 0 < s["events"] < 6676 and s["duration_s"] <= 0.07 + 1e-3


def test_replay_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "junk.aedat4"
    bad.write_bytes(b"not a recording at all")
    assert main(["replay", str(bad), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and "junk.aedat4" in err and "\n" not in err
    assert main(["replay", str(tmp_path / "missing.necrec")]) == 2
    assert main(["replay", str(bad), "--start", "2", "--end", "1"]) == 2


@needs_sample
def test_info_file(capsys, tmp_path):
    js = tmp_path / "i.json"
    assert main(["info", str(SAMPLE), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "aedat4" in out and "346 x 260" in out and "6,676" in out
    assert json.loads(js.read_text())["frames"] == 4


def test_headless_default_saves_to_a_file_and_says_so(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--duration", "0.1", "--controllers", "nec", "--no-prompt"]) == 0
    saved = list(tmp_path.glob("necviz-demo-*.rrd"))
    assert len(saved) == 1
    assert f"open it with: rerun {saved[0].name}" in capsys.readouterr().out


def test_a_bad_flag_never_truncates_an_existing_recording(tmp_path, capsys):
    rec = tmp_path / "keep.necrec"
    assert (
        main(
            [
                "demo",
                "--duration",
                "0.2",
                "--controllers",
                "nec",
                "--save",
                str(tmp_path / "a.rrd"),
                "--record",
                str(rec),
                "--no-prompt",
            ]
        )
        == 0
    )
    size = rec.stat().st_size
    for bad in (
        ["--save", str(tmp_path / "a.txt")],
        ["--speed", "abc"],
        ["--speed", "1e-300"],
        ["--tune-file", str(tmp_path / "missing")],
        ["--event-window-ms", "0"],
    ):
        args = [
            "demo",
            "--duration",
            "0.2",
            "--controllers",
            "nec",
            "--record",
            str(rec),
            "--force",
            "--no-prompt",
            *bad,
        ]
        if "--save" not in bad:
            args += ["--save", str(tmp_path / "b.rrd")]
        assert main(args) == 2, bad
        assert rec.stat().st_size == size, bad
    assert not (tmp_path / "b.rrd").exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("necviz: error:") == 5


@pytest.mark.parametrize("flags", [["--connect", "notaurl"], ["--json", "{tmp}/a-file/x.json"]])
def test_viewer_and_output_mistakes_are_one_line(tmp_path, capsys, flags):
    from test_pipeline import SENSOR, stream

    from necviz.drivers.recordings import Recorder

    (tmp_path / "a-file").write_text("a file where the folder of --json would be")
    flags = [f.format(tmp=tmp_path) for f in flags]
    with Recorder(tmp_path / "x.necrec", sensor=SENSOR, properties={}) as rec:
        for p in stream(n_frames=2):
            rec.write(p)
    assert main(["replay", str(tmp_path / "x.necrec"), "--save", str(tmp_path / "r.rrd"), *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("necviz: error:") and "Traceback" not in err and "\n" not in err.strip()
    assert err.startswith("necviz: error: --json") if "--json" in flags else err.startswith("necviz: error: viewer:")


@needs_sample
def test_replay_range_past_the_end_is_an_error(tmp_path, capsys):
    assert main(["replay", str(SAMPLE), "--start", "100", "--save", str(tmp_path / "r.rrd")]) == 2
    assert "past the end" in capsys.readouterr().err


def test_tuned_limits_must_fit_the_camera():
    from test_pipeline import ListSource, nec_lane

    from necviz.core.control import CameraLimits
    from necviz.pipeline import Pipeline

    src = ListSource([])
    src.camera_info = CameraInfo(CameraLimits(10, 19_000, 8.0))
    pipe = Pipeline(src, [nec_lane()])
    refused, ok = pipe.tune("exposure_max", 1_000_000), pipe.tune("exposure_max", 12_000)
    pipe._apply_changes()
    with pytest.raises(Exception, match="outside what the camera accepts"):
        refused.result(0)
    assert ok.result(0) and pipe.lanes["camera"].controller.limits.exposure_max_us == 12000


def test_live_at_real_time_pace_reacts_within_a_frame(tmp_path, capsys):
    """``live --speed 1`` on the emulated camera (issue 27 item 1): the emulated sensor is paced on the wall
    clock, never ahead of the loop, so NEC's exposure changes reach the next exposure or the one after
    (frames_late ≤ 1 in sensor time), and ``--json`` writes the summary per lane — once: an existing file is
    replaced only with --force."""
    out_json = tmp_path / "live.json"
    args = ["live", "--device", "emulated", "--scenario", "static_lab", "--duration", "1.5", "--speed", "1"]
    args += ["--save", str(tmp_path / "l.rrd"), "--json", str(out_json), "--no-prompt"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "reaction (sensor time)" in out and "processing p50" in out
    summary = json.loads(out_json.read_text())
    assert summary["run"]["speed"] == 1.0
    lane = summary["lanes"]["camera"]
    assert lane["frames"] >= 60 and lane["events"] > 0 and lane["commands"] > 0
    assert lane["changes_applied"] >= 3  # the static_lab's light steps were reacted to
    assert lane["frames_late"]["p99"] <= 1
    assert 0 < lane["command_to_exposure_us"]["p50"] <= 2 * 20_000  # within two 20 ms frame intervals
    assert summary["reader"]["lag_peak_us"] <= 100_000  # the reader's queue is bounded in sensor time
    before = out_json.read_text()
    (tmp_path / "l.rrd").unlink()
    assert main(args) == 2  # the --json file exists: refused, in one line, nothing overwritten
    err = capsys.readouterr().err
    assert "--json" in err and len(err.strip().splitlines()) == 1 and out_json.read_text() == before


def test_a_run_that_cannot_keep_its_speed_says_so(tmp_path, capsys):
    """--speed 1000 over 0.6 s of sensor time would need 0.6 ms of wall time: no machine keeps it,
    and the summary says how fast the run went instead of letting its figures pass for paced ones."""
    rrd = tmp_path / "fast.rrd"
    code = main(
        ["live", "--device", "emulated", "--duration", "0.6", "--speed", "1000", "--save", str(rrd), "--no-prompt"]
    )
    assert code == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if "not the 1000x asked" in ln]
    assert len(lines) == 1 and "ran at " in lines[0], out
    got = float(lines[0].split("ran at ")[1].split("x")[0])
    assert 0 <= got < 900  # (a loaded machine may print 0.00x)


def test_pace_note_only_for_a_paced_run_that_fell_behind():
    from necviz.dashboard.session import achieved_speed
    from necviz.wording import pace_note

    def note(asked, sensor_s, wall_s, settle_s=0.0):  # what the run's summary says (or the live count shows)
        return pace_note(asked, achieved_speed(sensor_s, wall_s, settle_s))

    assert note(None, 30.0, 47.8) is None  # --speed max: no pace was asked
    assert note(1.0, 30.0, 31.0) is None  # within 10 % of real time
    assert note(1.0, 30.0, 47.8) == "ran at 0.63x real time: latency and recovery are not real-time figures"
    assert note(1.0, 3.0, 1.5, settle_s=2.0) is None  # a running line waits for the start-up to pass
    assert "not the 4x asked" in note(4.0, 30.0, 15.0)
