"""The transfer ring of the DAVIS driver (:mod:`necviz.drivers.davis.transfers`): libusb1's asynchronous transfers
(on the emulator's stand-ins) and the pyusb fallback deliver the same bytes, in order, as the single read; out-of-order
completion, resubmission, cancellation at stop, timeouts, a stall, an unplug and an error; the options and the CLI."""

import io
import json
import sys
import time

import numpy as np
import pytest

from necviz.core.errors import NecvizError, ParameterError
from necviz.core.events import EventBatch
from necviz.core.sensor import SensorGeometry
from necviz.drivers.davis import CameraOptions, EmulatedDavis346, EmulatorOptions, Faults, open_camera
from necviz.drivers.davis import transfers as T
from necviz.drivers.davis.device import BulkReader, open_device
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError

SMALL = SensorGeometry(64, 48)


def backend(faults=None, **kw):
    kw.setdefault("duration_s", 0.2)
    kw.setdefault("sensor", SMALL)
    return EmulatedDavis346(EmulatorOptions(**kw), faults)


def raw_stream(kind, be=None, start=True, limit_s=20.0, **kw):
    """Every byte a reader of ``kind`` delivers (undecoded) from an emulated device, and how the stream ended."""
    be = backend() if be is None else be
    dev = open_device(be, emulated=True)
    dev.send_default_config(5000.0, 20_000.0)
    reader = (
        BulkReader(dev, **kw) if kind == "single" else (T.Libusb1Ring if kind == "libusb1" else T.PyusbRing)(dev, **kw)
    )
    if start:
        dev.start(settle_s=(0, 0, 0))
    reader.start()
    chunks, end = [], None
    deadline = time.monotonic() + (limit_s if start else 0.5)  # a device not started: 0.5 s of timeouts
    while time.monotonic() < deadline:
        item = reader.get(0.2)
        if item is None:
            continue
        if item[0] == "data":
            chunks.append(item[1])
            continue
        end = item
        break
    reader.stop()
    dev.close()
    return b"".join(chunks), end, reader, be


@pytest.fixture(scope="module")
def reference():
    data, end, _, _ = raw_stream("single")
    assert end[0] == "finished" and len(data) > 100_000
    return data


# -- options ----------------------------------------------------------------------------------------------------
def test_parse_transfers_accepts_n_bytes_and_refuses_nonsense_in_one_line():
    assert T.parse_transfers("8,8192") == (8, 8192)
    assert T.parse_transfers("4, 16k") == (4, 16384)
    assert T.parse_transfers("2,64KiB") == (2, 65536)
    for bad in ("8", "8,8192,1", "x,8192", "0,8192", "65,8192", "8,100", "8,0", "8,-1024", "8,8M", ""):
        with pytest.raises(ParameterError) as e:
            T.parse_transfers(bad)
        assert "\n" not in str(e.value)


def test_camera_options_default_to_the_single_read_and_the_rings_to_libcaers_size_with_more_in_flight():
    assert CameraOptions().usb == "single" and CameraOptions().transfer_size == 256 * 1024
    o = CameraOptions(usb="auto")
    assert (o.usb, o.transfers, o.transfer_size) == ("auto", 32, 8192)
    assert o.transfers * o.transfer_size == 256 * 1024  # what the single read buffers
    for bad in ({"usb": "winusb"}, {"transfers": 0}, {"transfer_size": 1000}, {"transfers": 8.5}):
        with pytest.raises(ParameterError):
            CameraOptions(**bad)


def test_auto_falls_back_to_pyusb_without_libusb1(monkeypatch):
    monkeypatch.setitem(sys.modules, "usb1", None)  # import usb1 raises ImportError
    assert T.libusb1_version() is None
    assert T.resolve_usb("auto") == "pyusb"
    with pytest.raises(ParameterError, match=r"needs the libusb1 package: pip install 'necviz\[usb\]'$"):
        T.resolve_usb("libusb1")
    assert "libusb1 not installed" in T.usb_library_line()
    cam = open_camera("emulated", backend=backend(duration_s=0.05), options=CameraOptions(usb="auto"))
    assert cam.usb_transfers == {"library": "pyusb", "transfers": 32, "transfer_bytes": 8192}
    assert sum(isinstance(p, EventBatch) for p in cam) > 0 and cam.state == "finished"


def test_statuses_are_libusbs():
    usb1 = pytest.importorskip("usb1")  # the [usb] extra; CI installs it
    for name in ("COMPLETED", "ERROR", "TIMED_OUT", "CANCELLED", "STALL", "NO_DEVICE", "OVERFLOW"):
        assert getattr(T, f"TRANSFER_{name}") == getattr(usb1, f"TRANSFER_{name}")
    assert T.resolve_usb("auto") == "libusb1"
    line = T.usb_library_line()
    assert line.startswith("USB library: pyusb, one 256 KiB read in flight (the default)")
    assert f"libusb1 {T.libusb1_version()} installed: --usb libusb1 keeps 32 x 8 KiB" in line


# -- the same bytes, in order --------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["libusb1", "pyusb"])
def test_rings_deliver_the_single_reads_bytes_in_order(kind, reference):
    data, end, reader, be = raw_stream(kind)
    assert end == ("finished", None)
    assert data == reference
    assert reader.stats["bytes"] == len(data)
    assert reader.stats["transfers"] > len(data) // 8192  # 8 KiB transfers, not 256 KiB
    if kind == "libusb1":
        h = be.libusb1_handle
        assert be.host_buffer_bytes == 0  # set for each read only (the room of the transfers in flight)
        assert reader.stats["out_of_order"] == 0
        n = reader.transfers
        assert len({u for u, _ in h.completions}) == n  # every transfer of the ring, each resubmitted as it completed
        assert h.submitted > n * 3
        assert not h._queue and h.closed  # nothing left in flight after the end


def test_out_of_order_completions_are_put_back_in_submission_order(reference):
    be = backend()
    be.libusb1_reorder = 5  # the stand-in fires five callbacks at a time, newest first
    data, end, reader, _ = raw_stream("libusb1", be)
    assert end == ("finished", None)
    assert reader.stats["out_of_order"] > 10
    assert data == reference


def test_transfers_the_fifo_fills_at_once_complete_together_and_are_decoded_together(reference):
    """A frame's readout (here 64 x 48 x 2 samples) fills the transfers waiting behind the one that ended full in
    one round of event handling, in order; the ring decodes what completed together in one call (45 decode calls
    per DAVIS346 frame at 8 KiB let a loaded host fall behind and the device's backlog delay every command)."""
    be = backend()
    data, end, reader, _ = raw_stream("libusb1", be, transfers=8, transfer_size=1024)
    assert end == ("finished", None) and data == reference
    assert reader.stats["out_of_order"] == 0
    assert reader.stats["joined"] > 0.3 * reader.stats["transfers"]
    done = be.libusb1_handle.completions
    assert len(done) > reader.stats["transfers"] - 1 and all(status == T.TRANSFER_COMPLETED for _, status in done[:-9])


@pytest.mark.parametrize("kind", ["single", "libusb1", "pyusb"])
def test_a_reader_thread_that_fails_ends_the_stream_in_one_line_instead_of_hanging(kind):
    """An exception that is not the device's (here the decoding) used to end the reader's thread silently: the
    consumer then waited forever (a live run stuck at 0 s of sensor time)."""

    def broken(data):
        raise ValueError("decoder bug")

    data, end, reader, _ = raw_stream(kind, limit_s=10.0, decode=broken)
    assert end is not None and end[0] == "error"
    assert str(end[1]) == "the reader thread failed: ValueError: decoder bug"


def test_stop_cancels_every_transfer_in_flight():
    be = backend(duration_s=None)  # an endless scene
    dev = open_device(be, emulated=True)
    dev.send_default_config(5000.0, 20_000.0)
    reader = T.Libusb1Ring(dev, decode=None)
    dev.start(settle_s=(0, 0, 0))
    reader.start()
    for _ in range(20):
        assert reader.get(5.0)[0] == "data"
    reader.stop()
    assert not reader.usb_thread.is_alive() and not reader.thread.is_alive()
    h = be.libusb1_handle
    assert not h._queue and h.closed
    assert reader.stats["cancelled"] >= 1
    assert any(status == T.TRANSFER_CANCELLED for _, status in h.completions)
    dev.close()


def test_timeouts_resubmit_and_deliver_nothing():
    data, end, reader, be = raw_stream("libusb1", start=False, timeout_ms=5)
    assert data == b"" and end is None
    assert reader.stats["timeouts"] >= 5
    assert be.libusb1_handle.submitted >= reader.stats["timeouts"]


def test_a_stall_is_cleared_once_all_transfers_are_back(reference):
    data, end, reader, be = raw_stream("libusb1", backend(Faults(stall_after_s=0.05)))
    assert end == ("finished", None)
    assert reader.stats["stalls"] == 1 and be.stalls == 1
    assert reader.stats["cancelled"] >= 1  # the transfers behind the stalled one were cancelled, then resubmitted
    assert any(r.direction == "clear_halt" for r in be.transfers)
    assert data == reference  # the emulated device holds its data while halted


def test_an_error_ends_the_stream_after_the_data_before_it(reference):
    be = backend()
    be.libusb1_inject = {30: T.TRANSFER_OVERFLOW}
    data, end, reader, _ = raw_stream("libusb1", be)
    assert end[0] == "error" and str(end[1]) == "bulk transfer 30 ended: overflow"
    assert 0 < len(data) < len(reference) and data == reference[: len(data)]


@pytest.mark.parametrize("usb", ["libusb1", "pyusb"])
def test_unplug_mid_stream_is_one_line_after_the_data_read_before(usb):
    if usb == "libusb1":
        pytest.importorskip("usb1")
    cam = open_camera(
        "emulated", backend=backend(Faults(unplug_after_s=0.1), duration_s=0.3), options=CameraOptions(usb=usb)
    )
    packets = []
    with pytest.raises(DeviceDisconnectedError) as err:
        for p in cam:
            packets.append(p)
    msg = str(err.value)
    assert "\n" not in msg and "was unplugged at t=0." in msg and isinstance(err.value, NecvizError)
    t = np.concatenate([p.events["t"] for p in packets if isinstance(p, EventBatch)])
    assert 0.08e6 < t[-1] <= 0.1e6 + 1000  # what was read before the unplug was delivered


def test_the_camera_streams_through_libusb1_with_the_sensor_time_bound():
    pytest.importorskip("usb1")
    cam = open_camera("emulated", backend=backend(duration_s=0.1), options=CameraOptions(usb="libusb1", buffer_s=0.01))
    it = iter(cam)
    first = next(it)
    time.sleep(0.5)  # the consumer pauses: the reader holds at most buffer_s of sensor time, then stops reading
    rest = list(it)
    st = cam.stats
    assert first is not None and rest and cam.state == "finished"
    assert st["backpressure_events"] >= 1 and st["lag_peak_us"] <= 0.01e6 + 2000
    assert cam.usb_transfers["library"] == "libusb1" and st["out_of_order"] == 0


def test_the_emulated_device_counts_the_transfers_in_flight_as_buffer():
    """While the stand-in reads one transfer, the room of it and of those queued behind it is buffering beside the
    device's FIFO, as a camera fills waiting transfers while the host is away."""
    be = backend(duration_s=0.05)
    seen = []
    read = be.bulk_read

    def spy(*a):
        seen.append(be.host_buffer_bytes)
        return read(*a)

    be.bulk_read = spy
    raw_stream("libusb1", be, transfers=4, transfer_size=2048)
    assert seen and max(seen) == 4 * 2048 and be.host_buffer_bytes == 0


def test_opening_transfers_on_an_unplugged_device_ends_as_disconnected():
    be = backend()
    dev = open_device(be, emulated=True)
    reader = T.Libusb1Ring(dev, decode=None)
    be.unplug()
    reader.start()
    item = reader.get(5.0)
    reader.stop()
    assert item[0] == "disconnected"
    with pytest.raises(DeviceError):
        dev.get(0, 0)


# -- the command line ------------------------------------------------------------------------------------------------
def test_live_usb_options_and_json(tmp_path):
    from necviz.commands.cli import main

    out = tmp_path / "live.json"
    argv = ["live", "--device", "emulated", "--scenario", "static_lab", "--duration", "0.2", "--speed", "max"]
    argv += ["--save", str(tmp_path / "l.rrd"), "--no-prompt", "--usb", "pyusb", "--usb-transfers", "4,16k"]
    argv += ["--json", str(out)]
    assert main(argv) == 0
    usb = json.loads(out.read_text())["usb"]
    assert usb == {"library": "pyusb", "transfers": 4, "transfer_bytes": 16384}


def test_live_refuses_nonsense_transfers_in_one_line(capsys):
    from necviz.commands.cli import main

    rc = main(["live", "--device", "emulated", "--no-prompt", "--usb-transfers", "8"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "--usb-transfers takes N,BYTES" in err and len(err.splitlines()) == 1


def test_live_refuses_transfers_for_the_single_read_in_one_line(capsys):
    from necviz.commands.cli import main

    rc = main(["live", "--device", "emulated", "--no-prompt", "--usb-transfers", "8,8k"])  # --usb single: the default
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--usb-transfers sets the rings (--usb libusb1, pyusb or auto)" in err
    assert len(err.splitlines()) == 1


def test_live_refuses_libusb1_without_the_package_and_usb_options_with_dv(monkeypatch, capsys):
    from necviz.commands.cli import main
    from necviz.options import LiveOptions

    with pytest.raises(ParameterError, match="not LiveOptions.device dv"):  # the library names its fields
        LiveOptions("dv", usb="pyusb")
    rc = main(["live", "--device", "dv", "--no-prompt", "--usb", "pyusb"])
    err = capsys.readouterr().err.strip()  # the command line names the flags
    assert (
        rc == 2 and "--usb and --usb-transfers set necviz's driver (--device usb or emulated), not --device dv" in err
    )
    assert len(err.splitlines()) == 1
    monkeypatch.setitem(sys.modules, "usb1", None)
    rc = main(["live", "--device", "emulated", "--no-prompt", "--usb", "libusb1"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == "necviz: error: --usb libusb1 needs the libusb1 package: pip install 'necviz[usb]'"


def test_devices_names_the_usb_library():
    from necviz.commands import devices

    buf = io.StringIO()
    devices.run(include_emulated=True, out=buf)
    assert T.usb_library_line() in buf.getvalue()
