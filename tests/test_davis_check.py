"""``necviz devices --check``: a camera's raw stream recorded, decoded again from the capture file, and judged.

The captures come from the emulated camera (as a user's would from a real one); what the check reports is
compared with what the emulator was told to send (its layout, exposure echo, geometry) and with the frames
the camera source decodes from the same stream.
"""

import io
import json

import numpy as np
import pytest

from necviz.core.errors import NecvizError
from necviz.core.frames import Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.davis import (
    CameraOptions,
    CameraVariant,
    DeviceError,
    EmulatedDavis346,
    EmulatorOptions,
    Faults,
    StreamLayout,
    open_camera,
)
from necviz.drivers.davis.capture import CaptureError, read_capture

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SMALL = SensorGeometry(64, 48)


def backend(faults=None, **kw):
    kw.setdefault("duration_s", 0.2)
    kw.setdefault("sensor", SMALL)
    kw.setdefault("seed", 2)
    return EmulatedDavis346(EmulatorOptions(**kw), faults)


def run_check(tmp_path, name="cap.davis", **kw):
    from necviz.commands.devices import check

    path = tmp_path / name
    buf = io.StringIO()
    code = check("emulated", capture_path=path, seconds=20, backend=backend(**kw), out=buf)
    return code, buf.getvalue().splitlines(), path


def line(lines, start):
    (hit,) = [s for s in lines if s.strip().startswith(start)]
    return hit


def test_check_reports_what_the_emulated_camera_sent_and_the_capture_decodes_again(tmp_path):
    code, lines, path = run_check(tmp_path, duration_s=1.4)  # more frames than the decoder keeps echoes of
    assert code == 0 and lines[-1].startswith("verdict: OK — ")
    assert "every frame echoed the exposure register exactly" in lines[-1]
    assert line(lines, "DAVIS346 EMU00346 (emulated)")
    assert "firmware 6, logic 18 (patch 1), chip DAVIS346B (id 5), master" in line(lines, "firmware")
    assert "ADC 30.240 MHz (30 MHz x 1.008)" in line(lines, "clocks")
    assert "DVS 64x48" in line(lines, "DVS") and "mono, global shutter" in line(lines, "DVS")
    assert line(lines, "first frame:").endswith("FS-GS exp×3 roi×8 (R adc×48 CE)×64 ES EE (S adc×48 CE)×64 FE")
    n_frames = int(line(lines, "frames").split()[1])
    assert n_frames >= 65  # 1.4 s at the 20 ms frame interval the check sets
    assert f"frames echoed it: {n_frames} exactly, 0 within 2 cycles, 0 off, 0 no value" in line(lines, "exposure")
    assert "151,200 cycles (5000 µs)" in line(lines, "exposure")  # 5000 µs x 30.24 MHz
    assert "transfers: one every" in line(lines, "transfers")

    # the capture file holds the stream: decoded again it gives the camera source's frames of the same scene
    cap = read_capture(path)
    assert not cap.truncated and cap.registers["exposure_cycles"] == 151_200 and len(cap.transfers) >= 1
    assert cap.device["serial"] == "EMU00346" and tuple(cap.device["dvs_size"]) == (64, 48)
    dec = cap.decoder()
    frames = [p for _, data in cap.transfers for p in dec.decode(data) if isinstance(p, Frame)]
    cam = open_camera("emulated", backend=backend(duration_s=1.4), options=CameraOptions(exposure_us=5000))
    ref = [p for p in cam if isinstance(p, Frame)]
    assert len(frames) == n_frames and len(ref) >= n_frames
    for a, b in zip(frames, ref, strict=False):
        assert np.array_equal(a.image, b.image) and a.exposure_us == b.exposure_us == 5000


def test_check_shows_a_camera_that_sends_another_layout(tmp_path):
    """ROI and exposure value before the frame start, no exposure specials, an echo one cycle off: the driver
    copes with all of it, and the check says each (a WARN), with the words as they came."""
    variant = CameraVariant(
        layout=StreamLayout(header="before", exposure_specials=False), echo_offset_cycles=1, dvs_orientation=4
    )
    code, lines, _ = run_check(tmp_path, variant=variant)
    assert code == 0 and lines[-1].startswith("verdict: WARN — ")
    assert "the logic sends no exposure specials: exposures are placed from the readout" in lines[-1]
    assert line(lines, "first frame:").endswith("exp×3 roi×8 FS-GS (R adc×48 CE)×64 (S adc×48 CE)×64 FE")
    assert "1 without exposure specials" in line(lines, "frames")
    n = int(line(lines, "frames").split()[1])
    assert f"0 exactly, {n} within 2 cycles" in line(lines, "exposure")
    assert line(lines, "echo - register:").strip() == f"echo - register: +1 ({n})"
    assert "DVS 64x48 (orientation 4)" in line(lines, "DVS")


def test_a_capture_cut_short_stays_readable_and_a_foreign_file_is_refused(tmp_path):
    from necviz.drivers.davis.check import analyse, report_lines

    _, _, path = run_check(tmp_path)
    whole = read_capture(path)
    cut = tmp_path / "cut.davis"
    cut.write_bytes(path.read_bytes()[:-3])
    part = read_capture(cut)
    assert part.truncated and len(part.transfers) == len(whole.transfers) - 1
    report = analyse(part)
    assert report.level == "WARN" and "the capture file is cut short" in report_lines(report)[-1]
    other = tmp_path / "other.bin"
    other.write_bytes(b"#!AER-DAT4.0\r\n" + bytes(100))
    with pytest.raises(CaptureError, match="not a necviz DAVIS capture") as err:
        read_capture(other)
    assert isinstance(err.value, NecvizError) and "\n" not in str(err.value)
    head = path.read_bytes()
    n = int.from_bytes(head[23:27], "little")
    damaged = tmp_path / "damaged.davis"
    damaged.write_bytes(head[:27] + b"x" + head[28 : 27 + n] + head[27 + n :])  # not JSON any more
    with pytest.raises(CaptureError, match="damaged capture header"):
        read_capture(damaged)
    assert json.loads(head[27 : 27 + n])["version"] == 1


def test_a_stream_with_no_complete_frame_fails_the_check(tmp_path):
    """Frames whose column counts are wrong (here: a ROI the readout does not match) are all dropped: FAIL,
    with the first frame's words to show why."""
    from necviz.drivers.davis.capture import Capture
    from necviz.drivers.davis.check import analyse, report_lines
    from necviz.drivers.davis.encoder import FrameTiming, StreamEncoder, cds_pair

    enc = StreamEncoder()
    reset, signal = cds_pair(np.full((4, 6), 10))
    words = np.concatenate(
        [enc.timestamp_reset(), enc.frame(FrameTiming(10, 20, 30, 40), reset, signal, roi=(0, 0, 6, 3))]
    )
    cap = Capture({"kind": "DAVIS346", "dvs_size": [8, 4], "aps_size": [8, 4]}, {"exposure_cycles": 0})
    cap.transfers = [(0, words.tobytes())]
    report = analyse(cap)
    assert report.level == "FAIL" and report.decoded["frames_dropped"] == 1
    assert "no complete frame" in report_lines(report)[-1]


def test_check_refuses_old_firmware_and_an_existing_capture_file(tmp_path):
    from necviz.commands.devices import check

    with pytest.raises(DeviceError, match="firmware version 5, older than the 6"):
        check("emulated", backend=backend(faults=Faults(firmware=5)), out=None)
    exists = tmp_path / "x.davis"
    exists.write_bytes(b"keep")
    with pytest.raises(NecvizError, match="exists already"):
        check("emulated", capture_path=exists, backend=backend(), out=None)
    assert exists.read_bytes() == b"keep"


def test_devices_cli_check_and_listing(tmp_path, capsys):
    from necviz.commands.cli import main
    from necviz.commands.devices import list_devices

    assert main(["devices", "--capture", str(tmp_path / "c")]) != 0
    assert "--capture and --seconds go with --check" in capsys.readouterr().err
    code = main(["devices"])
    text = capsys.readouterr().out
    assert "EMU00346" in text and "found " in text and "necviz live --device emulated" in text
    assert code == 0  # the emulated camera is usable
    if not [d for d in list_devices(include_emulated=False)]:
        assert "no DAVIS camera is attached" in text and "lsusb" in text
        assert main(["devices", "--no-emulated"]) == 1
        assert "found no usable camera" in capsys.readouterr().out
