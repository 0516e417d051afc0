"""--video: an H.264 MP4 that decodes with the layout's size, one frame per 1/fps of video time, the
duration the sensor time took divided by --speed, and the frames' pixels where the layout puts them."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

av = pytest.importorskip("av", reason="PyAV is not installed (pip install 'necviz[video]')")

from necviz.core.events import EVENT_DTYPE  # noqa: E402
from necviz.core.frames import Frame  # noqa: E402
from necviz.dashboard.video import LABEL_H, Canvas, VideoWriter  # noqa: E402
from necviz.telemetry import FrameRecord  # noqa: E402


def _decode(path):
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        return s.codec_context.name, s.width, s.height, frames, float(c.duration / 1e6)


def test_synthetic_stream_renders_where_the_layout_says(tmp_path):
    path = tmp_path / "v.mp4"
    w, h = 64, 48
    vw = VideoWriter(path, ["bright", "dark"], w, h, speed=0.5, fps=20)
    vw.started(0, {})
    for k in range(100):  # 100 ms of sensor time: 1 ms batches, a frame per lane every 10 ms
        t = k * 1000
        ev = np.zeros(10, EVENT_DTYPE)
        ev["t"], ev["x"], ev["y"], ev["p"] = t + np.arange(10), 5, 5, 1
        vw.events(ev)
        if k % 10 == 9:
            for lane, level in (("bright", 220), ("dark", 30)):
                f = Frame(np.full((h, w), level, np.uint8), t - 4000, t, 1.0, k)
                vw.frame(lane, f, FrameRecord(k, t - 4000, t, 4000.0, 1.0, 0.0, 0.0))
    stats = vw.close()
    codec, width, height, frames, duration = _decode(path)
    canvas = Canvas(["bright", "dark"], w, h)
    assert codec == "h264" and (width, height) == (canvas.width, canvas.height) == (stats["width"], stats["height"])
    # sensor span 0.099 s at x0.5 and 20 fps: frames at 0, 25 ms, 50 ms, 75 ms of sensor time
    assert len(frames) == stats["frames"] == 4
    assert duration == pytest.approx(len(frames) / 20, abs=1e-3)
    last = frames[-1].astype(int)
    for i, level in ((0, 220), (1, 30)):
        x, y = canvas.cell(i)
        panel = last[y + LABEL_H + 4 : y + LABEL_H + h - 4, x + 4 : x + w - 4]
        assert abs(panel.mean() - level) < 6  # H.264 is lossy, but not by much on flat grey
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]  # nothing partial left beside it


def test_demo_video_at_slow_motion(tmp_path):
    from necviz.commands.cli import main

    out = tmp_path / "demo.mp4"
    code = main(
        [
            "demo",
            "--duration",
            "0.3",
            "--controllers",
            "nec,fixed",
            "--video",
            str(out),
            "--speed",
            "0.25",
            "--video-fps",
            "24",
            "--save",
            str(tmp_path / "d.rrd"),
            "--no-prompt",
        ]
    )
    assert code == 0
    codec, width, height, frames, duration = _decode(out)
    canvas = Canvas(["nec", "fixed"], 346, 260)
    assert (codec, width, height) == ("h264", canvas.width, canvas.height)
    # ~0.3 s of sensor time at a quarter of real time: ~1.2 s of video, 24 frames a second
    assert duration == pytest.approx(0.3 / 0.25, abs=2 / 24)
    assert len(frames) == round(duration * 24)


def test_replay_video_and_refusals(tmp_path, capsys):
    from fuzz_corpus import SAMPLE_AEDAT4

    from necviz.commands.cli import main

    if SAMPLE_AEDAT4.is_file():
        out = tmp_path / "replay.mp4"
        assert main(["replay", str(SAMPLE_AEDAT4), "--video", str(out), "--save", str(tmp_path / "r.rrd")]) == 0
        codec, width, height, frames, duration = _decode(out)
        assert codec == "h264" and len(frames) == round(duration * 30) and duration == pytest.approx(0.17, abs=0.05)
    bad = tmp_path / "x.avi"
    assert main(["demo", "--duration", "0.1", "--video", str(bad), "--save", str(tmp_path / "y.rrd")]) == 2
    assert ".mp4" in capsys.readouterr().err


def test_frame_labels_print_short_exposures_in_microseconds():
    """Exposures under 5 µs printed as '0.00 ms' said nothing; below 1 ms the label is in microseconds."""
    from necviz.dashboard.video import exposure_text

    assert exposure_text(4.0) == "4.0 us"
    assert exposure_text(850) == "850 us"
    assert exposure_text(12_500) == "12.50 ms"
    assert "0.00" not in exposure_text(1.0)
