"""The DAVIS driver against libcaer's own tables and rules, checked on the emulated camera.

Independent truth: the values below are written out here from libcaer's public source
(github.com/inivation/libcaer, 3.3.9: ``src/davis_common.h`` ``davisCommonSendDefaultChipConfig`` for the
bias tables, ``src/davis.c`` ``caerBiasCoarseFineGenerate`` / ``caerBiasShiftedSourceGenerate`` for the
word layout), not imported from the driver; the words are encoded by the small functions of this file.
"""

import numpy as np
import pytest

from necviz.core.frames import Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.davis import CameraOptions, CameraVariant, EmulatedDavis346, EmulatorOptions, open_camera

SMALL = SensorGeometry(64, 48)


def backend(**kw):
    kw.setdefault("duration_s", 0.1)
    kw.setdefault("sensor", SMALL)
    return EmulatedDavis346(EmulatorOptions(**kw))


def cf_word(kind: str, coarse: int, fine: int) -> int:
    """libcaer's coarse/fine word: bit0 enabled, bit1 sexN, bit2 typeNormal, bit3 currentLevelNormal,
    fine << 4, coarse << 12; kinds as libcaer's CF_N_TYPE, CF_P_TYPE, CF_N_TYPE_CAS, CF_N_TYPE_OFF."""
    enabled, sex_n, type_normal = {
        "N": (1, 1, 1),
        "P": (1, 0, 1),
        "NCAS": (1, 1, 0),
        "NOFF": (0, 1, 1),
    }[kind]
    return enabled | sex_n << 1 | type_normal << 2 | 1 << 3 | fine << 4 | coarse << 12


def ss_word(ref: int, reg: int) -> int:
    """libcaer's shifted-source word in its default mode (SHIFTED_SOURCE, SPLIT_GATE): ref << 4 | reg << 10."""
    return ref << 4 | reg << 10


# libcaer davisCommonSendDefaultChipConfig, IS_DAVIS240 branch: parameter -> (kind, coarse, fine)
LIBCAER_DAVIS240 = {
    0: ("N", 4, 39),  # DIFFBN
    1: ("N", 5, 255),  # ONBN
    2: ("N", 4, 0),  # OFFBN
    3: ("NCAS", 5, 185),  # APSCASEPC
    4: ("NCAS", 5, 115),  # DIFFCASBNC
    5: ("N", 6, 219),  # APSROSFBN
    6: ("N", 5, 164),  # LOCALBUFBN
    7: ("N", 6, 144),  # PIXINVBN
    8: ("P", 2, 58),  # PRBP
    9: ("P", 1, 16),  # PRSFBP
    10: ("P", 4, 25),  # REFRBP
    11: ("N", 6, 91),  # AEPDBN
    12: ("N", 5, 49),  # LCOLTIMEOUTBN
    13: ("P", 4, 80),  # AEPUXBP
    14: ("P", 7, 152),  # AEPUYBP
    15: ("N", 5, 255),  # IFTHRBN
    16: ("N", 5, 255),  # IFREFRBN
    17: ("N", 7, 215),  # PADFOLLBN
    18: ("N", 6, 253),  # APSOVERFLOWLEVELBN
    19: ("N", 5, 254),  # BIASBUFFER
}


@pytest.mark.parametrize("chip_id, special_pixel", [(2, False), (0, True)])
def test_davis240_default_biases_are_libcaers(chip_id, special_pixel):
    """The four words that differed (OFFBN, APSCASEPC, DIFFCASBNC, PADFOLLBN) now match too; DAVIS240 A/B also
    get SPECIALPIXELCONTROL (139) = 0, which libcaer's davisCommonConfigSet passes on for those chips only."""
    be = backend(variant=CameraVariant(chip_id=chip_id))
    cam = open_camera("emulated", backend=be)
    assert cam.device.kind == "DAVIS240"
    want = {p: cf_word(*v) for p, v in LIBCAER_DAVIS240.items()} | {20: ss_word(1, 33), 21: ss_word(1, 33)}
    written = {p: v for m, p, v in be.writes() if m == 5 and p < 128}
    assert written == want
    chip = {p: v for m, p, v in be.writes() if m == 5 and p >= 128}
    assert (139 in chip) == special_pixel and chip.get(139, 0) == 0
    assert not {143, 144} & set(chip)  # gray counter and ADC test exist on the newer chips only
    cam.close()


def test_davis240_frames_decode_with_libcaers_doubled_samples():
    """libcaer doubles a DAVIS240's ADC samples (davisCommonEventTranslator); the emulated DAVIS240 encodes half,
    so the decoded frames equal the ones of the same scene on a DAVIS346 id."""
    got = {}
    for chip_id in (5, 2):
        cam = open_camera("emulated", backend=backend(seed=3, variant=CameraVariant(chip_id=chip_id)))
        got[chip_id] = [p for p in cam if isinstance(p, Frame)]
    assert len(got[2]) == len(got[5]) >= 3
    for a, b in zip(got[2], got[5], strict=True):
        assert np.array_equal(a.image, b.image)


def test_davis346_default_biases_are_libcaers():
    """The DAVIS346 table (libcaer's DAVIS128/208/346/640 branch), every word."""
    table = {
        8: ("N", 5, 164),
        9: ("NOFF", 7, 215),
        10: ("N", 4, 39),
        11: ("N", 5, 255),
        12: ("N", 4, 1),
        13: ("N", 6, 144),
        14: ("P", 2, 58),
        15: ("P", 1, 16),
        16: ("P", 4, 25),
        17: ("P", 6, 20),
        18: ("N", 6, 219),
        19: ("P", 5, 20),
        20: ("N", 0, 1),
        21: ("P", 6, 60),
        22: ("N", 5, 49),
        23: ("N", 6, 91),
        24: ("P", 4, 80),
        25: ("P", 7, 152),
        26: ("N", 5, 255),
        27: ("N", 5, 255),
        34: ("N", 5, 254),
    }
    vdac = {0: (27, 6), 1: (21, 6), 2: (32, 7), 3: (1, 7), 4: (21, 7)}  # (voltage, current): voltage | current << 6
    want = {p: cf_word(*v) for p, v in table.items()} | {p: v | c << 6 for p, (v, c) in vdac.items()}
    want |= {35: ss_word(1, 33), 36: ss_word(1, 33)}
    be = backend()
    cam = open_camera("emulated", backend=be, options=CameraOptions())
    assert {p: v for m, p, v in be.writes() if m == 5 and p < 128} == want
    cam.close()


def stream(be):
    """(events, frames, sensor) of a whole emulated run."""
    from necviz.core.events import EventBatch

    cam = open_camera("emulated", backend=be)
    packets = list(cam)
    ev = np.concatenate([p.events for p in packets if isinstance(p, EventBatch)])
    return ev, [p for p in packets if isinstance(p, Frame)], cam.sensor


@pytest.mark.parametrize("dvs, aps", [(4, 0), (0, 4), (4, 5), (4, 6), (4, 7), (0, 3)])
def test_orientation_bits_change_the_wire_format_not_the_output(dvs, aps):
    """X/Y inversion (bit 2) and flips as libcaer reads them: the size registers count the chip's columns and
    rows (swapped when inverted; populateDeviceInfo in src/davis.c), DVS row words carry x when inverted
    (davisCommonEventTranslator), APS readout order follows the bits (apsUpdateFrame). The same scene seen
    through any orientation decodes to the same events and frames in output coordinates."""
    plain = stream(backend(seed=5))
    be = backend(seed=5, aps_orientation=aps, variant=CameraVariant(dvs_orientation=dvs))
    cols_rows = (be.reg(1, 0), be.reg(1, 1)), (be.reg(2, 0), be.reg(2, 1))
    assert cols_rows[0] == ((48, 64) if dvs & 4 else (64, 48)) and cols_rows[1] == ((48, 64) if aps & 4 else (64, 48))
    ev, frames, sensor = stream(be)
    assert sensor == SMALL and ev.size > 1000
    assert np.array_equal(ev, plain[0])
    assert len(frames) == len(plain[1]) >= 3
    for a, b in zip(frames, plain[1], strict=True):
        assert np.array_equal(a.image, b.image)


@pytest.mark.parametrize(
    "layout, lost",
    [
        (dict(header="before"), 0),  # ROI and exposure value before the frame start
        (dict(exposure_specials=False), 1),  # no exposure specials: the first frame teaches the decoder
        (dict(header="before", exposure_specials=False), 1),
    ],
)
def test_emulated_layouts_decode_to_the_same_frames(layout, lost):
    """Each word layout a camera may send gives the frames of the default layout, as libcaer accepts them all
    (apsEndFrame checks column counts only); without exposure specials the decoder places the exposure from
    the readout and only the first frame (which taught it) is lost."""
    from necviz.drivers.davis import StreamLayout

    plain = stream(backend(seed=6))
    cam = open_camera("emulated", backend=backend(seed=6, variant=CameraVariant(layout=StreamLayout(**layout))))
    frames = [p for p in cam if isinstance(p, Frame)]
    assert len(plain[1]) >= 4 and len(frames) == len(plain[1]) - lost
    for a, b in zip(frames, plain[1][lost:], strict=True):
        assert np.array_equal(a.image, b.image)
        assert (a.exposure_start_us, a.exposure_end_us) == (b.exposure_start_us, b.exposure_end_us)
    st = cam.stats
    assert st["frames_dropped"] == 0 and st["frames_without_exposure"] == lost and st["skipped_words"] == 0


@pytest.mark.parametrize("offset", [1, -2])
def test_an_exposure_echo_off_by_a_cycle_still_applies_the_command_and_its_gain(offset):
    """The frame's reported exposure (misc10, ADC cycles) need not equal the register; libcaer never compares
    them (autoexposure.c only reads it). A command is applied at the first frame echoing its value within a
    couple of cycles, and its digital gain reaches the frames from then on. (The command is sent before the
    stream starts, so which frame takes it does not depend on how far the emulator runs ahead.)"""
    be = backend(duration_s=0.15, variant=CameraVariant(echo_offset_cycles=offset))
    cam = open_camera("emulated", backend=be, options=CameraOptions(exposure_us=4000))
    cam.set_exposure("camera", 1500.0, gain=2.0)
    frames = [p for p in cam if isinstance(p, Frame)]
    (cmd,) = cam.commands()
    assert cmd.applied_start_us == frames[0].exposure_start_us
    assert len(frames) >= 5 and all(f.exposure_us == 1500 and f.gain == 2.0 for f in frames)
    assert be.reg(2, 12) == round(1500 * 30.24)  # the register; each frame echoed it + offset


def test_command_log_matches_within_the_tolerance_and_prefers_the_newest():
    from necviz.drivers.command_log import CommandLog

    log = CommandLog(2, 1e-3)
    log.issue(100, 1000.0, 1.5, 30_240)
    log.issue(200, 1001.0, 2.0, 30_270)
    log.issue(300, 2000.0, 3.0, 60_480)
    assert log.frame(250, 30_900) == 1.0  # matches nothing (630 cycles off): no command applied yet
    assert log.frame(250, 30_268) == 2.0  # the newest issued before the start that matches (2 cycles off)
    recs = log.records()
    assert [r.applied_start_us for r in recs] == [None, 250, None]  # the older one was superseded
    assert log.frame(320, 60_480 + 60) == 3.0  # 0.1 % of 60,480 cycles is 60
    assert log.frame(400, 30_240) == 3.0  # no command waits any more: the gain stays


def test_colour_davis_frames_are_demosaiced():
    """A colour DAVIS346 (APS COLOR_FILTER = 1, RGBG) streams a Bayer mosaic; the driver reads the filter from the
    device and demosaics as libcaer does. The emulated scene is neutral grey, so the demosaiced grey keeps the
    mono camera's brightness (interpolation changes the texture, not the mean)."""
    mono = stream(backend(seed=7))[1]
    cam = open_camera("emulated", backend=backend(seed=7, variant=CameraVariant(color_filter=1)))
    assert cam.info["color_filter"] == 1 and cam._decoder is None
    frames = [p for p in cam if isinstance(p, Frame)]
    assert len(frames) == len(mono) >= 3
    for a, b in zip(frames, mono, strict=True):
        assert abs(a.image.mean() - b.image.mean()) < 1.0
    assert any(not np.array_equal(a.image, b.image) for a, b in zip(frames, mono, strict=True))


def test_a_timestamp_reset_while_streaming_keeps_time_increasing():
    """MUX TIMESTAMP_RESET pulses while the camera streams: the device clock restarts at 0 (the emulator, like
    the logic, sends the reset word); the driver keeps one increasing clock, delivers the reset trigger in
    order, drops at most the frame in progress and counts none of its words as garbage."""
    from necviz.core.events import EventBatch
    from necviz.core.imu import TriggerBatch

    cam = open_camera("emulated", backend=backend(duration_s=0.3, seed=8))
    packets, frames, resets = [], 0, 0
    for p in cam:
        packets.append(p)
        frames += isinstance(p, Frame)
        if frames == 4 and resets == 0:
            cam.device.reset_timestamps()
            resets = 1
    times = [int(p.events["t"][0]) for p in packets if isinstance(p, EventBatch)]
    assert times == sorted(times)
    trig = [int(t) for p in packets if isinstance(p, TriggerBatch) for t in p.triggers["t"]]
    assert len(trig) == 2  # the stream's opening reset and the pulse
    i = next(k for k, p in enumerate(packets) if isinstance(p, TriggerBatch) and int(p.triggers["t"][0]) == trig[1])
    before = [p for p in packets[:i] if isinstance(p, EventBatch)]
    after = [p for p in packets[i + 1 :] if isinstance(p, EventBatch)]
    assert before and after and int(before[-1].events["t"][-1]) <= trig[1] <= int(after[0].events["t"][0])
    st = cam.stats
    assert st["frames"] >= 10 and st["frames_dropped"] <= 1 and st["skipped_words"] == 0
