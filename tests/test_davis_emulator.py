"""The emulated DAVIS346 behind pyusb, driven through the real driver path.

Independent truths: the start/stop order and register numbers are written out here from
docs/davis-protocol.md (libcaer's ``dataStart``/``dataStop``; not imported from the driver); the exposure register is
checked against µs x (ADC MHz x deviation / 1000) read back from SYSINFO; decoded frames are compared
with a separately built simulator with the same scene, seed and exposure.
"""

import struct
import time

import numpy as np
import pytest
import usb.core
import usb.util

from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.davis import CameraOptions, EmulatedDavis346, EmulatorOptions, open_camera
from necviz.drivers.source import Source

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SMALL = SensorGeometry(64, 48)


def backend(**kw):
    kw.setdefault("duration_s", 0.3)
    kw.setdefault("sensor", SMALL)
    return EmulatedDavis346(EmulatorOptions(**kw))


def read_reg(dev, module, param):
    return struct.unpack(">I", bytes(dev.ctrl_transfer(0xC0, 0xBF, module, param, 4)))[0]


def test_pyusb_finds_the_emulated_device_and_reads_its_descriptors():
    be = backend()
    dev = usb.core.find(idVendor=0x152A, backend=be)
    assert dev is not None and (dev.idVendor, dev.idProduct) == (0x152A, 0x841A)
    assert dev.bcdDevice & 0xFF == 6
    assert dev.serial_number == "EMU00346"
    assert dev.get_active_configuration().bConfigurationValue == 1
    eps = [e.bEndpointAddress for e in dev.get_active_configuration()[(0, 0)]]
    assert 0x82 in eps
    usb.util.dispose_resources(dev)


def test_register_file_single_and_multiple_requests():
    be = backend()
    dev = usb.core.find(idVendor=0x152A, backend=be)
    assert read_reg(dev, 6, 0) == 18  # logic version
    assert (read_reg(dev, 1, 0), read_reg(dev, 1, 1)) == (64, 48)  # DVS size
    dev.ctrl_transfer(0x40, 0xBF, 2, 13, struct.pack(">I", 123456))
    assert read_reg(dev, 2, 13) == 123456
    payload = struct.pack(">BBI", 1, 32, 9) + struct.pack(">BBI", 3, 7, 2)
    dev.ctrl_transfer(0x40, 0xC2, 2, 0, payload)
    assert (read_reg(dev, 1, 32), read_reg(dev, 3, 7)) == (9, 2)
    assert be.writes() == [(2, 13, 123456), (1, 32, 9), (3, 7, 2)]
    dev.ctrl_transfer(0x40, 0xBF, 6, 0, struct.pack(">I", 3))  # SYSINFO is read-only
    assert read_reg(dev, 6, 0) == 18
    with pytest.raises(usb.core.USBError):
        dev.ctrl_transfer(0x40, 0xAB, 0, 0, b"")  # unknown request: EP0 stalls
    usb.util.dispose_resources(dev)


# documented dataStart and dataStop order (docs/davis-protocol.md, after libcaer's src/davis.c)
STOP_ALL = [
    (1, 3, 0),
    (2, 4, 0),
    (3, 2, 0),
    (3, 3, 0),
    (3, 4, 0),
    (4, 0, 0),
    (0, 0, 0),
    (0, 1, 0),
    (9, 0, 0),
    (0, 3, 0),
]
RUN_CHIP = [(0, 3, 1)]
TRANSPORT = [(9, 0, 1), (0, 1, 1), (0, 0, 1)]
PRODUCERS = [(1, 3, 1), (2, 4, 1), (3, 2, 1), (3, 3, 1), (3, 4, 1), (4, 0, 1)]
RUN_PARAMS = {(m, p) for m, p, _ in STOP_ALL}


def test_start_and_stop_follow_the_documented_order_and_pauses():
    be = backend(duration_s=0.05)
    cam = open_camera("emulated", backend=be)
    config_writes = len(be.writes())
    packets = list(cam)  # runs to the end of the scenario, then closes (stop sequence)
    assert any(isinstance(p, Frame) for p in packets)
    recs = list(be.transfers)
    run_recs = [
        r for r in recs if r.direction == "clear_halt" or (r.direction == "out" and (r.module, r.param) in RUN_PARAMS)
    ]
    seq = [("halt",) if r.direction == "clear_halt" else (r.module, r.param, r.value) for r in run_recs]
    expected_start = STOP_ALL + [("halt",)] + RUN_CHIP + TRANSPORT + PRODUCERS
    assert seq[: len(expected_start)] == expected_start
    # stop: producers off, then MUX/timestamps/USB, then the chip
    stop = seq[len(expected_start) :]
    assert stop == [
        (1, 3, 0),
        (2, 4, 0),
        (3, 2, 0),
        (3, 3, 0),
        (3, 4, 0),
        (4, 0, 0),
        (0, 0, 0),
        (0, 1, 0),
        (9, 0, 0),
        (0, 3, 0),
    ]
    t = {r[:3]: rec.t_s for r, rec in zip(seq, run_recs, strict=True)}
    assert t[(9, 0, 1)] - t[(0, 3, 1)] >= 0.19  # 200 ms bias settle after RUN_CHIP
    assert t[(1, 3, 1)] - t[(0, 0, 1)] >= 0.045  # 50 ms before the producers
    # the default configuration (biases etc.) came before any run bit
    first_run = next(i for i, r in enumerate(recs) if r.direction == "out" and (r.module, r.param) in RUN_PARAMS)
    assert len([r for r in recs[:first_run] if r.direction == "out"]) == config_writes
    # DAVIS346 default biases (coarse, fine): ONBN N(5,255) = 0xF | 255<<4 | 5<<12; PRBP P(2,58) = 0xD | 58<<4 | 2<<12
    assert be.reg(5, 11) == 0xF | 255 << 4 | 5 << 12 and be.reg(5, 14) == 0xD | 58 << 4 | 2 << 12
    assert be.reg(5, 0) == 27 | 6 << 6  # VDAC APSOVERFLOWLEVEL (27, 6)


def test_exposure_register_is_microseconds_times_actual_adc_clock():
    be = backend()
    cam = open_camera("emulated", backend=be, options=CameraOptions(exposure_us=5000))
    dev = cam.device.dev
    adc = read_reg(dev, 6, 4) * read_reg(dev, 6, 6) / 1000  # SYSINFO ADC clock x deviation
    assert adc != read_reg(dev, 6, 4)  # the deviation matters in this test
    assert be.reg(2, 12) == round(5000 * adc)
    assert be.reg(2, 13) == round(20_000 * adc)  # frame interval (20 ms default)
    for us in (10.0, 1234.5, 18_000.0):
        cam.set_exposure("camera", us)
        assert be.reg(2, 12) == round(us * adc)
    cam.set_exposure("camera", 1e9)  # clamped to the limit
    assert be.reg(2, 12) == round(cam.limits.exposure_max_us * adc)
    cam.close()


def test_decoded_frames_are_the_simulators_frames():
    """Same scene, seed and exposure: the driver path reproduces the simulator's images and times exactly."""
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.rig import SimRig
    from necviz.drivers.sim.scenes import make_scenario

    scene = make_scenario("tunnel_exit", sensor=SMALL, duration_us=200_000, seed=4)
    rig = SimRig(
        scene, {"camera": (3000.0, 1.0)}, aps=ApsParams(frame_interval_us=20_000, exposure_max_us=19_000), seed=4
    )
    want = [p for _, p in rig.packets() if isinstance(p, Frame)]
    cam = open_camera("emulated", backend=backend(seed=4, duration_s=0.2), options=CameraOptions(exposure_us=3000))
    assert isinstance(cam, Source)
    got = [p for p in cam if isinstance(p, Frame)]
    assert len(got) == len(want) >= 8
    for g, w in zip(got, want, strict=True):
        assert (g.exposure_start_us, g.exposure_end_us) == (w.exposure_start_us, w.exposure_end_us)
        assert np.array_equal(g.image, w.image)
    assert cam.state == "finished"
    assert cam.stats["skipped_words"] == 0


def test_emulator_honours_the_exposure_register_in_closed_loop_and_gain_is_digital():
    cam = open_camera("emulated", backend=backend(duration_s=0.3), options=CameraOptions(exposure_us=4000))
    frames, markers = [], []
    for p in cam:
        if isinstance(p, Frame):
            frames.append(p)
            if len(frames) == 3:
                cam.set_exposure("camera", 1500.0, gain=2.0)
        elif isinstance(p, ExposureMarker):
            markers.append(p)
    (cmd,) = cam.commands()
    assert cmd.applied_start_us is not None and cmd.applied_start_us > frames[2].exposure_end_us
    before = [f for f in frames if f.exposure_start_us < cmd.applied_start_us]
    after = [f for f in frames if f.exposure_start_us >= cmd.applied_start_us]
    assert after and all(f.exposure_us == 4000 and f.gain == 1.0 for f in before)
    assert all(f.exposure_us == 1500 and f.gain == 2.0 for f in after)
    # gain 2 is digital: every pixel is an even number or saturated (clip(round(2 Z)))
    img = after[0].image.astype(int)
    assert np.all((img % 2 == 0) | (img == 255))
    assert 2 * len(frames) == len(markers)


def test_realtime_pacing_follows_the_wall_clock():
    cam = open_camera("emulated", backend=backend(duration_s=0.4, realtime=True))
    first = last = None
    for p in cam:
        if isinstance(p, EventBatch) and len(p):
            now = time.monotonic()
            first = first or (now, int(p.events["t"][0]))
            last = (now, p.t_last_us)
    wall = last[0] - first[0]
    stream = (last[1] - first[1]) / 1e6
    assert stream > 0.3 and wall >= stream - 0.05


def test_roi_frames_keep_sensor_coordinates():
    """APS ROI (inclusive sensor pixels): the frame keeps the sensor's shape, zero outside the ROI."""
    full = [p for p in open_camera("emulated", backend=backend(duration_s=0.1, seed=2)) if isinstance(p, Frame)]
    cam = open_camera("emulated", backend=backend(duration_s=0.1, seed=2))
    cam.device.set_roi(10, 5, 40, 30)
    roi = [p for p in cam if isinstance(p, Frame)]
    assert len(roi) == len(full) >= 3
    for a, b in zip(roi, full, strict=True):
        assert a.image.shape == SMALL.shape
        assert np.array_equal(a.image[5:31, 10:41], b.image[5:31, 10:41])
        mask = np.ones(SMALL.shape, bool)
        mask[5:31, 10:41] = False
        assert not a.image[mask].any()


def test_a_control_transfer_does_not_wait_for_the_simulation():
    """While the emulated sensor is being simulated (held here inside the realtime data path), an exposure
    write is served at once: a real device's control endpoint does not wait for its sensor (issue 27)."""
    import threading

    from necviz.drivers.davis.device import DavisDevice, find_devices

    be = EmulatedDavis346(EmulatorOptions(duration_s=0.3, sensor=SensorGeometry(64, 48), realtime=True))
    dev = DavisDevice(find_devices(be)[0], be, emulated=True)
    dev.send_default_config()
    dev.start(settle_s=(0, 0, 0))
    import array

    buf = array.array("B", bytes(64 * 1024))
    dev.read(buf, 500)  # streaming
    inside, release = threading.Event(), threading.Event()
    produce = be._produce

    def slow_produce(until=None):
        inside.set()
        release.wait(5.0)
        return produce(until)

    be._produce = slow_produce
    reader = threading.Thread(target=lambda: dev.read(buf, 500), daemon=True)
    reader.start()
    assert inside.wait(5.0)  # the data path is simulating now
    done = threading.Event()
    writer = threading.Thread(target=lambda: (dev.set_exposure_us(1234), done.set()), daemon=True)
    writer.start()
    served = done.wait(2.0)
    release.set()
    reader.join(5.0)
    be._produce = produce
    assert served  # the write did not wait for the simulation to finish
    from necviz.drivers.davis import protocol as P

    assert be.reg(P.APS.MODULE, P.APS.EXPOSURE) == dev.us_to_cycles(1234)
    dev.close()
