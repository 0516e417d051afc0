"""``--device dv``: the dv-processing camera adapter, run over the vendor's own recording reader on a real
DAVIS346 recording (the reader and the camera share the getNextEventBatch/getNextFrame/... interface).

Independent truth: necviz's AEDAT 4 reader (``drivers/recordings/aedat4.py``, on the ``aedat`` package, not
dv-processing) reads the same file; the adapter must deliver exactly its events, frames, IMU samples and
triggers, in the stream order every source keeps. Only the setters are checked on a stand-in.
"""

import datetime
import sys

import numpy as np
import pytest
from conftest import SHARED_DATA

from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.drivers.davis import CameraOptions, DeviceError, DeviceNotFoundError

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SAMPLE = SHARED_DATA / "davis346_sample.aedat4"


def dv_module():
    dv = pytest.importorskip("dv_processing", reason="iniVation's dv-processing is not installed (necviz[dv])")
    if not SAMPLE.exists():
        pytest.skip(f"the real recording {SAMPLE} is not here")
    return dv


def split(packets):
    """(events, frames, imu, triggers, markers) checking the stream-order contract on the way."""
    evs, frames, imu, trg, markers = [], [], [], [], []
    last_t, open_start, last_pair = -1, None, None
    for p in packets:
        if isinstance(p, EventBatch):
            assert int(p.events["t"][0]) >= last_t
            last_t = int(p.events["t"][-1])
            evs.append(p.events)
        elif isinstance(p, ExposureMarker):
            assert p.t_us >= last_t
            last_t = p.t_us
            markers.append((p.kind, p.t_us))
            if p.kind == "start":
                assert open_start is None
                open_start = p.t_us
            else:
                last_pair, open_start = (open_start, p.t_us), None
        elif isinstance(p, Frame):
            assert (p.exposure_start_us, p.exposure_end_us) == last_pair
            frames.append(p)
        elif isinstance(p, ImuBatch):
            imu.append(p.samples)
        elif isinstance(p, TriggerBatch):
            trg.append(p.triggers)
    cat = lambda xs, dt: np.concatenate(xs) if xs else np.zeros(0, dt)  # noqa: E731
    return cat(evs, EVENT_DTYPE), frames, cat(imu, IMU_DTYPE), cat(trg, TRIGGER_DTYPE), markers


@pytest.fixture(scope="module")
def reference():
    """The file as necviz's own AEDAT 4 reader (the ``aedat`` package) sees it."""
    dv_module()
    from necviz.drivers.recordings.aedat4 import Aedat4Recording

    return split(list(Aedat4Recording(SAMPLE)))


def same_as_reference(got, ref, triggers=None):
    """``got`` holds the file's events, frames and IMU samples, and its triggers (or ``triggers``)."""
    ev, frames, imu, trg, _ = got
    rev, rframes, rimu, rtrg, _ = ref
    assert ev.size == 6676 and np.array_equal(ev, rev)
    assert len(frames) == len(rframes) == 4
    for a, b in zip(frames, rframes, strict=True):
        assert (a.exposure_start_us, a.exposure_end_us) == (b.exposure_start_us, b.exposure_end_us)
        assert a.exposure_us == 500 and a.image.shape == (260, 346) and np.array_equal(a.image, b.image)
    assert imu.size == rimu.size == 160 and np.array_equal(imu["t"], rimu["t"])
    for k in ("ax", "ay", "az", "gx", "gy", "gz", "temp"):
        np.testing.assert_allclose(imu[k], rimu[k], rtol=1e-6)
    assert abs(float(np.median(imu["ay"])) + 1.0) < 0.05  # resting on the table: 1 g along -y
    assert np.array_equal(trg, rtrg if triggers is None else triggers)


def test_recording_through_the_adapter_is_what_necviz_reads_from_the_file(reference):
    dv = dv_module()
    from necviz.drivers.dv_camera import DvCamera

    cam = DvCamera(dv.io.MonoCameraRecording(str(SAMPLE)), live=False)
    assert cam.sensor.shape == (260, 346) and cam.sensor.name == "DAVIS346"
    got = split(list(cam))
    same_as_reference(got, reference)
    assert [k for k, _ in got[4]] == ["start", "end"] * 4
    assert cam.state == "finished" and cam.stats["frames"] == 4 and cam.stats.get("frames_late", 0) == 0


class LiveRecording:
    """A recording presented as a live camera, delivering what libcaer's packet containers would: each poll
    returns every event, IMU sample and trigger up to the stream clock, and a frame once its readout is over
    (9 ms after its exposure, as this file's APS triggers show). The clock advances 1 ms whenever the adapter
    finds nothing new (it then asks ``isRunning``). ``announce``: "file" keeps the file's triggers (its APS
    exposure triggers announce frames 2-4 and a fifth exposure whose frame the file does not hold), "none"
    drops the APS triggers, "every" announces every frame's exposure as a live DAVIS does (at the frame's
    own times)."""

    READOUT_US = 9_000

    def __init__(self, dv, announce: str):
        rec = dv.io.MonoCameraRecording(str(SAMPLE))
        self._dv = dv
        self.events = dv.EventStore()
        while (e := rec.getNextEventBatch()) is not None:
            self.events.add(e)
        self.frames = []
        while (f := rec.getNextFrame()) is not None:
            self.frames.append(f)
        self.imu = []
        while (b := rec.getNextImuBatch()) is not None:
            self.imu += list(b)
        self.triggers = []
        while (b := rec.getNextTriggerBatch()) is not None:
            self.triggers += [t for t in b if announce == "file" or int(t.type) < 6]
        if announce == "every":
            for f in self.frames:
                s, e = f.timestamp, f.timestamp + f.exposure.microseconds
                self.triggers += [
                    dv.Trigger(s, dv.TriggerType.APS_EXPOSURE_START),
                    dv.Trigger(e, dv.TriggerType.APS_EXPOSURE_END),
                ]
        self.triggers.sort(key=lambda t: t.timestamp)
        self.clock = self.events.getLowestTime()
        self.served = {"events": self.clock - 1}  # per stream: delivered up to here
        self.calls = []

    def getNextEventBatch(self):
        start = self.served["events"] + 1
        if start > self.clock:
            return None
        self.served["events"] = self.clock
        out = self.events.sliceTime(start, self.clock + 1)
        return out if out.size() else None

    def _take(self, items, vector):
        due = [x for x in items if x.timestamp <= self.clock]
        if not due:
            return None
        del items[: len(due)]
        out = vector()
        for x in due:
            out.append(x)
        return out

    def getNextFrame(self):
        f = self.frames[0] if self.frames else None
        if f is not None and f.timestamp + f.exposure.microseconds + self.READOUT_US <= self.clock:
            return self.frames.pop(0)
        return None

    def getNextImuBatch(self):
        return self._take(self.imu, self._dv.IMUPacket.ImuVector)

    def getNextTriggerBatch(self):
        return self._take(self.triggers, self._dv.TriggerPacket.TriggersVector)

    def getEventResolution(self):
        return (346, 260)

    def getCameraName(self):
        return "DAVIS346_00000002"

    def isRunning(self):
        self.clock += 1000
        return True

    @property
    def stream_finished(self):
        done = self.served["events"] >= self.events.getHighestTime()
        return done and not self.frames and not self.imu and not self.triggers

    # the setters, recorded (a recording has none; a camera's are checked here on this stand-in)
    def setExposureDuration(self, td):
        self.calls.append(("exposure", td))

    def setFrameInterval(self, td):
        self.calls.append(("frame_interval", td))


def run_live(dv, announce, on_packet=None):
    from necviz.drivers.dv_camera import DvCamera

    live = LiveRecording(dv, announce)
    cam = DvCamera(live, live=True, options=CameraOptions(frame_interval_us=40_000, exposure_us=500))
    packets, delays = [], []
    for p in cam:
        packets.append(p)
        if isinstance(p, EventBatch):
            delays.append((int(p.events["t"][0]), live.clock - int(p.events["t"][0])))
        if on_packet is not None:
            on_packet(cam, p)
    return cam, live, packets, delays


@pytest.mark.parametrize("announce", ["file", "none", "every"])
def test_live_camera_path_delivers_the_recording_in_stream_order(reference, announce):
    """Polled as a camera, with the file's own APS exposure triggers, none or one per frame, the adapter
    delivers exactly what the file holds. Announced exposures let events outside exposures through at once;
    without them every event waits about a frame interval (the hold-back that lets a late frame's markers go
    first)."""
    dv = dv_module()
    cam, live, packets, delays = run_live(dv, announce)
    trg = None  # the file's
    if announce != "file":  # no APS triggers; or the exposure begin (8) and end (9) of every frame
        rframes = reference[1]
        pairs = [(t, k) for f in rframes for t, k in ((f.exposure_start_us, 8), (f.exposure_end_us, 9))]
        trg = np.array(pairs if announce == "every" else [], TRIGGER_DTYPE)
    same_as_reference(split(packets), reference, trg)
    assert cam.state == "finished" and cam.stats.get("frames_late", 0) == 0
    assert cam.stats["exposures_without_frame"] == (1 if announce == "file" else 0)
    if announce == "file":
        return
    frames = split(packets)[1]
    busy = [(f.exposure_start_us, f.exposure_end_us + LiveRecording.READOUT_US + 2000) for f in frames]
    last = frames[-1].exposure_start_us  # after it the end of the stream releases everything
    free = [d for t, d in delays if t < last and not any(s <= t <= e for s, e in busy)]
    assert len(free) > 10
    if announce == "every":
        assert max(free) <= 12_000  # one event batch (10 ms in this file) and a poll step
    else:
        assert min(free) >= 40_000 - 10_000


def test_commands_reach_the_setters_and_apply_with_their_gain(reference):
    """The setters get dv-processing's timedelta arguments; a frame whose exposure matches a command marks it
    applied and carries its digital gain (this file's frames are exposed 500 µs)."""
    dv = dv_module()
    sent = []

    def command(cam, p):
        if isinstance(p, Frame) and not sent:
            sent.append(p.exposure_end_us)
            cam.set_exposure("camera", 500.0, gain=2.0)
            cam.set_exposure("camera", 1e9)  # clamped to the frame interval minus the readout allowance

    cam, live, packets, _ = run_live(dv, "every", command)
    assert live.calls[:2] == [
        ("exposure", datetime.timedelta(microseconds=500)),
        ("frame_interval", datetime.timedelta(microseconds=40_000)),
    ]
    assert live.calls[2:] == [
        ("exposure", datetime.timedelta(microseconds=500)),
        ("exposure", datetime.timedelta(microseconds=39_000)),
    ]
    first, clamped = cam.commands()
    assert first.applied_start_us is not None and clamped.applied_start_us is None
    frames = [p for p in packets if isinstance(p, Frame)]
    ref = reference[1]
    for f, r in zip(frames, ref, strict=True):
        if f.exposure_start_us >= first.applied_start_us:
            assert f.gain == 2.0 and np.array_equal(f.image, np.clip(2 * r.image.astype(int), 0, 255))
        else:
            assert f.gain == 1.0
    assert frames[-1].gain == 2.0


def test_without_the_dv_extra_the_error_says_how_to_install_it(monkeypatch, capsys, tmp_path):
    from necviz.commands.cli import main
    from necviz.drivers.dv_camera import open_dv_camera

    monkeypatch.setitem(sys.modules, "dv_processing", None)  # an import of it now fails
    with pytest.raises(DeviceError) as err:
        open_dv_camera()
    assert str(err.value) == "--device dv needs iniVation's dv-processing: pip install 'necviz[dv]'"
    code = main(["live", "--device", "dv", "--duration", "1", "--save", str(tmp_path / "x.rrd"), "--no-prompt"])
    out = capsys.readouterr()
    assert code != 0 and "pip install 'necviz[dv]'" in out.err and len(out.err.strip().splitlines()) == 1


def test_no_dv_camera_attached_says_so():
    dv_module()
    from necviz.drivers.dv_camera import find_dv_cameras, open_dv_camera

    if find_dv_cameras():
        pytest.skip("a DAVIS camera is attached")
    with pytest.raises(DeviceNotFoundError, match="dv-processing finds no DAVIS camera"):
        open_dv_camera()


def test_nec_runs_on_the_adapter_as_on_any_source():
    """The adapter is a Source: NEC (P-TEDI underneath) accepts its markers and frames and commands it."""
    dv = dv_module()
    from necviz.core.control import make_controller
    from necviz.drivers.dv_camera import DvCamera
    from necviz.drivers.source import Source

    cam = DvCamera(LiveRecording(dv, "every"), live=True, options=CameraOptions(frame_interval_us=40_000))
    assert isinstance(cam, Source) and cam.camera_info.limits.exposure_max_us == 39_000
    ctl = make_controller("nec", sensor=cam.sensor, limits=cam.limits, exposure_us=500)
    frames = 0
    for name, p in cam.packets():
        assert name in (None, "camera")
        cmd = ctl.feed(p)
        if cmd is not None:
            cam.set_exposure("camera", cmd.exposure_us, cmd.gain)
        frames += isinstance(p, Frame)
    assert frames == 4 and cam.commands_issued >= 1


def test_reconnect_is_refused_with_the_dv_backend(tmp_path, capsys):
    from necviz.commands.cli import main

    code = main(["live", "--device", "dv", "--reconnect", "--save", str(tmp_path / "x.rrd"), "--no-prompt"])
    err = capsys.readouterr().err
    assert code != 0 and "--reconnect works with necviz's driver (--device usb), not with --device dv" in err


class BiasedLiveRecording(LiveRecording):
    """The stand-in camera with dv-processing's bias and filter setters (a ``dv.io.camera.DAVIS`` cannot be opened
    without hardware): it records each call; its bias enum is dv-processing's own."""

    def __init__(self, dv, announce: str):
        super().__init__(dv, announce)
        self.Davis346BiasCF = dv.io.camera.DAVIS.Davis346BiasCF
        self.bias_calls = []
        self.filter_calls = []

    def getCameraName(self):
        return "DAVIS346_00000499"

    def setDavis346BiasCoarseFine(self, bias, coarse, fine):
        self.bias_calls.append((bias, coarse, fine))

    def setBackgroundActivityFilter(self, steps):
        self.filter_calls.append(("ba", steps))

    def setRefractoryPeriodFilter(self, steps):
        self.filter_calls.append(("refr", steps))


def _dv_pipeline(dv):
    from necviz.core.control import make_controller
    from necviz.drivers.dv_camera import DvCamera
    from necviz.pipeline import Lane, Pipeline

    fake = BiasedLiveRecording(dv, "every")
    cam = DvCamera(fake, live=True, options=CameraOptions(frame_interval_us=40_000))
    lane = Lane("camera", make_controller("nec", sensor=cam.sensor, limits=cam.limits))
    return fake, Pipeline(cam, [lane], warm_up=False)


def test_dvs_controls_reach_dv_processings_bias_setters():
    """``--device dv``: a DVS control becomes dv-processing coarse/fine setter calls, one per bias word that
    core/biases.py computes for it (its libcaer encoding decoded to coarse/fine), on the enum member that names
    that bias; P-TEDI follows; the FPGA filter in 250 µs steps."""
    dv = dv_module()
    from necviz.core.biases import BIAS_ADDRESSES, CoarseFine, DvsState

    fake, pipe = _dv_pipeline(dv)
    assert pipe.dvs.available
    msg, _ = pipe.dvs.set("c_on", 0.15, None, started=False)
    E = dv.io.camera.DAVIS.Davis346BiasCF
    expected = DvsState(pipe.dvs.state.model).request("c_on", 0.15).words()  # from libcaer's defaults
    assert expected, "a lower ON threshold moves at least one bias"
    names = {a: n for n, a in BIAS_ADDRESSES["DAVIS346"].items()}
    members = {"DIFFBN": E.Diff, "ONBN": E.On, "OFFBN": E.Off}
    cfs = [(names[a], CoarseFine.parse(w)) for a, w in sorted(expected.items())]
    want = [(members[n], cf.coarse, cf.fine) for n, cf in cfs]
    assert fake.bias_calls == want
    assert pipe.dvs.state.settings().c_on == pytest.approx(0.15, rel=0.01)
    assert pipe.lanes["camera"].estimator.params.c_on == pytest.approx(0.15, rel=0.01)
    pipe.dvs.set("refractory_us", 50.0, None, started=False)
    assert fake.bias_calls[-1][0] == E.Refractory
    assert pipe.dvs.state.settings().refractory_us == pytest.approx(50.0, rel=0.05)
    pipe.dvs.set("ba_filter_us", 1000, None, started=False)
    assert fake.filter_calls == [("ba", 4)]  # the refractory filter, unchanged (off), is not written


def test_a_dv_control_without_a_setter_is_refused_and_changes_nothing():
    dv = dv_module()
    from necviz.core.errors import ParameterError

    fake, pipe = _dv_pipeline(dv)
    pipe.dvs.set("c_off", 0.2, None, started=False)
    before = (len(fake.bias_calls), pipe.dvs.state.current, pipe.lanes["camera"].estimator.params)
    with pytest.raises(ParameterError, match="no setter for the DAVIS346's bias IFTHRBN; nothing was written"):
        pipe.dvs.set("bias.IfThrBn", "5/100", None, started=False)
    with pytest.raises(ParameterError, match="cannot switch the filter off"):
        pipe.dvs.set("ba_filter_us", 0, None, started=False)
    assert (len(fake.bias_calls), pipe.dvs.state.current, pipe.lanes["camera"].estimator.params) == before
    assert fake.filter_calls == []
