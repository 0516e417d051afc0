"""The streaming pipeline and the Rerun sink: control never waits, drops are counted, faults flush."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import rerun as rr
from rrd_read import Rrd

from necviz import schema as S
from necviz.core.control import CameraLimits, make_controller
from necviz.core.errors import NecvizError, ParameterError, StreamError
from necviz.core.event_image import EventImage
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, ImuBatch
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import packet_time_us
from necviz.dashboard.sink import RerunSink, SinkOptions
from necviz.drivers.recordings import Recorder, open_recording
from necviz.drivers.source import CameraInfo, Source, route
from necviz.pipeline import Lane, Pipeline, RecorderObserver

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SENSOR = SensorGeometry(32, 24, "test")


class ListSource(Source):
    """A single-camera source over a packet list; records commands; may fail after ``fail_after`` packets."""

    cameras = ("camera",)
    camera_info = CameraInfo()

    def __init__(self, packets, fail_after=None):
        self.sensor = SENSOR
        self.now_us = 0
        self.packets_ = packets
        self.fail_after = fail_after
        self.commands = []
        self.closed = False

    def __iter__(self):
        for i, p in enumerate(self.packets_):
            if self.fail_after is not None and i == self.fail_after:
                raise NecvizError("camera unplugged (test)")
            self.now_us = packet_time_us(p) or self.now_us
            yield p

    def packets(self):
        return route("camera", self)

    def set_exposure(self, camera, exposure_us, gain=1.0, *, issue_time_us=None):
        assert camera == "camera"
        self.commands.append((self.now_us if issue_time_us is None else issue_time_us, exposure_us, gain))

    def close(self):
        self.closed = True

    def warm_up(self) -> None:
        pass


def stream(n_frames=10, period_us=10_000, exposure_us=2_000, level=120, brighten_at=None, seed=0):
    """Events at 200 kev/s (balanced, or net ON after ``brighten_at``), frames of a flat scene."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_frames):
        t0 = 1_000 + k * period_us
        for b in range(period_us // 1_000):
            ev = np.zeros(200, EVENT_DTYPE)
            ev["t"] = np.sort(rng.integers(t0 + b * 1_000, t0 + (b + 1) * 1_000, 200))
            ev["x"] = rng.integers(0, SENSOR.width, 200)
            ev["y"] = rng.integers(0, SENSOR.height, 200)
            on = 0.5 if brighten_at is None or t0 < brighten_at else 0.9
            ev["p"] = np.where(rng.random(200) < on, 1, -1)
            if b == 0:
                out.append(ExposureMarker(t0, "start"))
            out.append(EventBatch(ev))
            if b == exposure_us // 1_000 - 1:
                out.append(ExposureMarker(t0 + exposure_us, "end"))
                img = np.full(SENSOR.shape, level, np.uint8)
                out.append(Frame(img, t0, t0 + exposure_us, 1.0, k))
    return out


def nec_lane(drives=True, name="camera"):
    ctrl = make_controller("nec", sensor=SENSOR, limits=CameraLimits(10, 8_000, 4.0), exposure_us=2_000)
    return Lane(name, ctrl, drives=drives)


def open_rec(path):
    rec = rr.RecordingStream("necviz-test")
    rec.save(str(path))
    return rec


def test_commands_go_back_to_the_source_between_frames(tmp_path):
    src = ListSource(stream(n_frames=12, brighten_at=40_000))
    lane = nec_lane()
    pipe = Pipeline(src, [lane])
    stats = pipe.run().finish()
    frame_ends = [p.exposure_end_us for p in src.packets_ if isinstance(p, Frame)]
    assert stats["frames"] == 12 and stats["events"] == 12 * 10 * 200
    tel = pipe.telemetry["camera"]
    assert len(src.commands) == tel.commands + 1  # + the initial setting
    between = [t for t, _, _ in src.commands[1:] if t not in frame_ends]
    assert between, "NEC should command on event batches, not only on frames"
    assert tel.latency.count == tel.commands and stats["lanes"]["camera"]["latency_p50_us"] > 0
    assert src.closed


def test_open_loop_lane_never_commands_the_source():
    src = ListSource(stream(n_frames=6, brighten_at=20_000))
    pipe = Pipeline(src, [nec_lane(drives=False)])
    pipe.run().finish()
    assert src.commands == [] and pipe.telemetry["camera"].commands > 0


def test_source_error_ends_the_run_and_everything_before_it_is_kept(tmp_path):
    packets = stream(n_frames=8)
    src = ListSource(packets, fail_after=len(packets) // 2)
    rec = open_rec(tmp_path / "run.rrd")
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, SinkOptions(lossless=True))
    recorder = Recorder(tmp_path / "run.necrec", sensor=SENSOR, properties={})
    pipe = Pipeline(src, [nec_lane()], observers=[sink, RecorderObserver(recorder, "camera")]).start()
    assert pipe.wait(30)
    with pytest.raises(NecvizError, match="unplugged"):
        pipe.finish()
    rr.disconnect(rec)
    frames_before = sum(isinstance(p, Frame) for p in packets[: len(packets) // 2])
    assert Rrd(tmp_path / "run.rrd").rows["camera/frame"] == frames_before
    replayed = [p for p in open_recording(tmp_path / "run.necrec") if isinstance(p, Frame)]
    assert len(replayed) == frames_before


def test_stop_ends_a_running_pipeline_promptly(tmp_path):
    class Endless(ListSource):
        def __iter__(self):
            t = 0
            while True:
                t += 1_000
                ev = np.zeros(10, EVENT_DTYPE)
                ev["t"] = t
                yield EventBatch(ev)

    pipe = Pipeline(Endless([]), [nec_lane()], speed=1.0).start()
    time.sleep(0.2)
    assert pipe.running
    pipe.stop()
    assert pipe.wait(5)
    stats = pipe.finish()
    assert 50_000 <= stats["duration_s"] * 1e6 <= 2_000_000  # paced at real time: ~0.2 s of sensor time


def test_stop_after_limits_sensor_time():
    pipe = Pipeline(ListSource(stream(n_frames=10)), [nec_lane()], stop_after_s=0.03)
    stats = pipe.run().finish()
    assert stats["duration_s"] <= 0.031 and stats["frames"] <= 3


def test_imu_packets_pass_through_to_the_recorder(tmp_path):
    packets = stream(n_frames=2)
    imu = np.zeros(3, IMU_DTYPE)
    imu["t"] = [1_500, 1_600, 1_700]
    packets.insert(2, ImuBatch(imu))
    recorder = Recorder(tmp_path / "imu.necrec", sensor=SENSOR, properties={})
    Pipeline(ListSource(packets), [nec_lane()], observers=[RecorderObserver(recorder, "camera")]).run().finish()
    got = [p for p in open_recording(tmp_path / "imu.necrec") if isinstance(p, ImuBatch)]
    assert sum(len(p) for p in got) == 3


def _stuck_sink(tmp_path, monkeypatch, **options):
    """A sink whose worker hangs in its first event window (a viewer that stopped reading)."""
    rec = open_rec(tmp_path / "slow.rrd")
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, SinkOptions(**options))
    release = threading.Event()
    monkeypatch.setattr(sink, "_draw_window", lambda *window: release.wait(30))
    return rec, sink, release


def test_a_slow_viewer_never_slows_the_control_path(tmp_path, monkeypatch):
    """The sink's worker is stuck; the stream still runs through, what the viewer misses is counted, and
    the sink holds at most the window the worker is stuck in and one more (33 ms windows of 1 ms batches
    of 200 events: 33 batches a window, over ``queue_size``, so a new window replaces one still waiting,
    and over ``max_backlog`` 64 once two wait, so later windows are skipped: which of the two happens
    depends on when the worker took the first)."""
    rec, sink, release = _stuck_sink(tmp_path, monkeypatch, frame_queue_size=2, queue_size=16, max_rate_hz=1e6)
    src = ListSource(stream(n_frames=20))
    t0 = time.perf_counter()
    Pipeline(src, [nec_lane()], observers=[sink]).run()
    elapsed = time.perf_counter() - t0
    summary = sink.summary()
    waiting = sink._waiting_batches()
    release.set()
    sink.close()
    rr.disconnect(rec)
    assert elapsed < 5.0  # a control path waiting for the stuck viewer would take 30 s
    assert summary["frames_dropped"] >= 20 - 2 - 1
    assert waiting <= 2 * 34
    assert summary["event_images_skipped"] + summary["event_batches_dropped"] >= 3  # 6 windows closed, 2 kept
    assert summary["events_decimated"] >= summary["events_seen"] - 2 * 34 * 200


def test_a_slow_viewer_costs_the_oldest_windows_when_nothing_is_skipped(tmp_path, monkeypatch):
    """With no backlog limit the waiting windows are bounded by ``queue_size`` batches: the oldest are
    dropped and counted (batches and events), the newest kept."""
    rec, sink, release = _stuck_sink(
        tmp_path, monkeypatch, queue_size=40, max_backlog=100_000, max_rate_hz=1e6, frame_queue_size=2
    )
    Pipeline(ListSource(stream(n_frames=20)), [nec_lane()], observers=[sink]).run()
    summary = sink.summary()
    waiting = sink._waiting_batches()
    release.set()
    sink.close()
    rr.disconnect(rec)
    # 6 windows closed: the first stuck in the worker, the newest waiting, the 4 between dropped on arrival
    assert 33 <= waiting <= 34 + 34
    assert summary["event_batches_dropped"] >= 3 * 33
    assert summary["events_seen"] >= summary["event_batches_dropped"] * 200


def test_sink_decimates_by_stride_and_counts(tmp_path):
    rec = open_rec(tmp_path / "dec.rrd")
    options = SinkOptions(event_window_us=10_000, max_events_per_window=500, lossless=True)
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, options)
    src = ListSource(stream(n_frames=5))
    Pipeline(src, [nec_lane()], observers=[sink]).run()
    s = sink.close()
    rr.disconnect(rec)
    assert s["events_seen"] == 5 * 10 * 200
    assert s["events_drawn"] + s["events_decimated"] == s["events_seen"]
    assert s["events_drawn"] <= s["event_images"] * 500
    assert s["events_drawn"] >= s["events_seen"] // 5  # stride 4 at 2000 events per window, not more
    r = Rrd(tmp_path / "dec.rrd")
    _, rate = r.series(S.EVENT_RATE)
    assert np.allclose(rate[1:-1], 200 * 1e6 / 1_000)  # 200 events per ms (the first window starts 1 ms late)


def test_thinned_event_images_count_their_events_as_not_drawn(tmp_path):
    """``image_period_us`` thins the event images by sensor time; the events of a thinned window are not
    drawn and are counted so: drawn + decimated = seen, as for skipped and strided windows."""
    rec = open_rec(tmp_path / "thin.rrd")
    options = SinkOptions(event_window_us=10_000, image_period_us=30_000, lossless=True)
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, options)
    Pipeline(ListSource(stream(n_frames=10)), [nec_lane()], observers=[sink]).run()
    s = sink.close()
    rr.disconnect(rec)
    assert s["event_images_thinned"] >= 5  # 10 windows of 10 ms, an image at most every 30 ms
    assert s["events_drawn"] + s["events_decimated"] == s["events_seen"] == 10 * 10 * 200


def test_event_image_counts_and_colours():
    ev = np.zeros(5, EVENT_DTYPE)
    ev["x"], ev["y"], ev["p"] = [1, 1, 1, 2, 3], [0, 0, 0, 1, 2], [1, 1, -1, -1, 1]
    img = EventImage(4, 5, saturate_at=1.0)
    assert img.add(ev) == 5
    assert img.counts_on[0, 1] == 2 and img.counts_off[0, 1] == 1 and img.counts_off[1, 2] == 1
    rgb = img.render()
    assert rgb.shape == (4, 5, 3)
    assert rgb[0, 1, 2] > rgb[0, 1, 0]  # net ON: blue
    assert rgb[1, 2, 0] > rgb[1, 2, 2]  # OFF: red
    assert (rgb[3, 4] == rgb[0, 0]).all()  # no events: background
    img.clear()
    assert img.counts_on.sum() == 0
    assert img.add(ev, stride=2) == 3


def test_bad_pipeline_parameters():
    with pytest.raises(ParameterError):
        Pipeline(ListSource([]), [])
    with pytest.raises(ParameterError):
        Pipeline(ListSource([]), [nec_lane()], speed=0)
    with pytest.raises(ParameterError):
        Pipeline(ListSource([]), [nec_lane(name="a"), nec_lane(name="b")])


def test_a_gap_in_the_stream_costs_one_window_not_one_per_window(tmp_path):
    """An hour-long pause in a recording must not make the sink draw 100,000 empty images."""
    a, b = stream(n_frames=2), stream(n_frames=2)
    later = []
    for p in b:  # the same packets, an hour later
        if isinstance(p, EventBatch):
            q = p.events.copy()
            q["t"] += 3_600_000_000
            later.append(EventBatch(q))
        elif isinstance(p, ExposureMarker):
            later.append(ExposureMarker(p.t_us + 3_600_000_000, p.kind))
        else:
            later.append(
                Frame(
                    p.image,
                    p.exposure_start_us + 3_600_000_000,
                    p.exposure_end_us + 3_600_000_000,
                    p.gain,
                    p.sequence + 2,
                )
            )
    rec = open_rec(tmp_path / "gap.rrd")
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, SinkOptions(lossless=True))
    t0 = time.perf_counter()
    Pipeline(ListSource(a + later), [nec_lane()], observers=[sink]).run().finish()
    rr.disconnect(rec)
    assert time.perf_counter() - t0 < 10
    s = sink.summary()
    assert s["events_seen"] == 4 * 10 * 200 and s["event_images"] <= 6


def test_stop_is_prompt_even_inside_a_paced_gap():
    packets = stream(n_frames=1)
    tail = np.zeros(5, EVENT_DTYPE)
    tail["t"] = 3_600_000_000  # an hour later: paced at real time, the thread waits for it
    pipe = Pipeline(ListSource(packets + [EventBatch(tail)]), [nec_lane()], speed=1.0).start()
    time.sleep(0.3)
    t0 = time.perf_counter()
    stats = pipe.finish()
    assert time.perf_counter() - t0 < 2.0
    assert stats["events"] == 10 * 200 and not pipe.running


def test_a_source_yielding_bare_event_arrays_is_an_error_not_silence():
    """Events travel as EventBatch: a bare array (the packet of sources written before it) must end the run
    with a clear error, not be dropped while the controllers see no events."""
    packets = stream(n_frames=2)
    legacy = [p.events if isinstance(p, EventBatch) else p for p in packets]
    pipe = Pipeline(ListSource(legacy), [nec_lane()])
    with pytest.raises(StreamError, match="the source yielded a ndarray, which is not a stream packet"):
        pipe.run().finish()
    assert pipe.telemetry.events == 0
