"""necviz export: every reader format -> every writer format, read back equal; ranges cut right;
outputs never destroy inputs; the AEDAT 4 files open in iniVation's dv-processing and in ``aedat``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fuzz_corpus import SAMPLE_AEDAT4, build_seeds

from necviz.commands.cli import main
from necviz.commands.export import run as export
from necviz.commands.replay import open_for_replay
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.drivers.recordings import RecordingError, open_recording
from necviz.io import FAERY_DTYPE, TONIC_DTYPE, from_faery, from_tonic, load_npz, to_faery, to_tonic
from necviz.options import ExportOptions

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

OUTPUTS = (".aedat4", ".h5", ".npz", ".necrec")
EXPOSURE_US = 2000.0  # for the inputs that store none (MVSEC, RPG text)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    folder = tmp_path_factory.mktemp("seeds")
    return {f"{s.format}:{s.path.name}": s.path for s in build_seeds(folder)}


def _content(packets) -> dict:
    """Everything a stream held: events, frames (pixels, exposure, gain), IMU samples, triggers."""
    ev, frames, imu, trg = [], [], [], []
    for p in packets:
        if isinstance(p, EventBatch):
            ev.append(p.events)
        elif isinstance(p, Frame):
            frames.append(p)
        elif isinstance(p, ImuBatch):
            imu.append(p.samples)
        elif isinstance(p, TriggerBatch):
            trg.append(p.triggers)
    return {
        "events": np.concatenate(ev) if ev else np.zeros(0, EVENT_DTYPE),
        "frames": frames,
        "imu": np.concatenate(imu) if imu else np.zeros(0, IMU_DTYPE),
        "triggers": np.concatenate(trg) if trg else np.zeros(0, TRIGGER_DTYPE),
    }


def _read_input(path, start_s=None, end_s=None) -> dict:
    rec, _ = open_for_replay(path, EXPOSURE_US, start_s, end_s)
    try:
        return _content(rec)
    finally:
        rec.close()


def _read_output(path: Path) -> dict:
    if path.suffix == ".npz":
        z = load_npz(path)
        frames = [
            Frame(img, int(s), int(e), float(g), i)
            for i, (img, s, e, g) in enumerate(
                zip(z["frames"], z["frame_exposure_start_us"], z["frame_exposure_end_us"], z["frame_gain"], strict=True)
            )
        ]
        return {"events": z["events"], "frames": frames, "imu": z["imu"], "triggers": z["triggers"]}
    rec = open_recording(path)
    try:
        return _content(rec)
    finally:
        rec.close()


def _assert_same(got: dict, want: dict, suffix: str) -> None:
    assert got["events"].dtype == EVENT_DTYPE
    np.testing.assert_array_equal(got["events"], want["events"])
    assert len(got["frames"]) == len(want["frames"])
    for a, b in zip(got["frames"], want["frames"], strict=True):
        assert (a.exposure_start_us, a.exposure_end_us) == (b.exposure_start_us, b.exposure_end_us)
        np.testing.assert_array_equal(a.image, b.image)
        if suffix != ".aedat4":  # AEDAT 4 has no field for the digital gain
            assert a.gain == b.gain
    for key in ("imu", "triggers"):
        assert len(got[key]) == len(want[key])
        for field in want[key].dtype.names:
            np.testing.assert_array_equal(got[key][field], want[key][field])


@pytest.mark.parametrize("suffix", OUTPUTS)
def test_every_reader_format_round_trips_through_every_writer(seeds, suffix, tmp_path):
    formats_seen = set()
    for name, path in seeds.items():
        want = _read_input(path)
        out = tmp_path / (name.replace(":", "_").replace(".", "_") + suffix)
        stats = export(ExportOptions(path, out, exposure_us=EXPOSURE_US), out=None)
        got = _read_output(out)
        _assert_same(got, want, suffix)
        assert stats["counts"]["events"] == len(want["events"])
        assert stats["counts"]["frames"] == len(want["frames"])
        formats_seen.add(name.split(":")[0])
    expected = {"necviz", "aedat3", "aedat2", "rosbag1", "rosbag2", "hdf5", "rpg-text"}
    assert expected <= formats_seen
    # the seeds between them carry frames, IMU and triggers: the round trip covered all of them
    assert any(len(_read_input(p)["frames"]) for p in seeds.values())
    assert any(len(_read_input(p)["imu"]) for p in seeds.values())


@pytest.mark.parametrize("suffix", OUTPUTS)
def test_start_and_end_cut_the_same_span_as_replay(seeds, suffix, tmp_path):
    cut = 0
    for name, path in seeds.items():
        full = _read_input(path)
        t = full["events"]["t"]
        if len(t) < 10:
            continue
        origin = _origin(path)
        span = (int(t[-1]) - origin) / 1e6
        start_s, end_s = round(span * 0.25, 6), round(span * 0.75, 6)
        want = _read_input(path, start_s, end_s)
        out = tmp_path / (name.replace(":", "_").replace(".", "_") + "_cut" + suffix)
        export(ExportOptions(path, out, start_s=start_s, end_s=end_s, exposure_us=EXPOSURE_US), out=None)
        got = _read_output(out)
        _assert_same(got, want, suffix)
        # an independent check of the cut: exactly the events inside [start, end) of the full stream
        lo, hi = origin + int(np.ceil(start_s * 1e6 - 1e-6)), origin + int(np.ceil(end_s * 1e6 - 1e-6))
        inside = full["events"][(t >= lo) & (t < hi)]
        np.testing.assert_array_equal(got["events"], inside)
        for f in got["frames"]:
            assert lo <= f.exposure_start_us and f.exposure_end_us <= hi
        cut += 1
    assert cut >= 6


def _origin(path) -> int:
    rec, origin = open_for_replay(path, EXPOSURE_US)
    rec.close()
    return origin


@pytest.mark.skipif(not SAMPLE_AEDAT4.is_file(), reason="the real DAVIS346 sample (../shared/data) is not here")
def test_real_recording_round_trips_with_frames_imu_and_triggers(tmp_path):
    want = _read_input(SAMPLE_AEDAT4)
    assert len(want["frames"]) == 4 and len(want["imu"]) and len(want["triggers"])
    for suffix in OUTPUTS:
        out = tmp_path / f"sample{suffix}"
        export(ExportOptions(SAMPLE_AEDAT4, out), out=None)
        _assert_same(_read_output(out), want, suffix)
    # and back again: the exported AEDAT 4 exported once more is the same stream
    again = tmp_path / "again.h5"
    export(ExportOptions(tmp_path / "sample.aedat4", again), out=None)
    _assert_same(_read_output(again), want, ".h5")


@pytest.mark.skipif(not SAMPLE_AEDAT4.is_file(), reason="the real DAVIS346 sample (../shared/data) is not here")
@pytest.mark.parametrize("compression", ["lz4", "zstd", "none"])
def test_aedat4_opens_in_the_aedat_reader(tmp_path, compression):
    import aedat

    want = _read_input(SAMPLE_AEDAT4)
    out = tmp_path / "sample.aedat4"
    export(ExportOptions(SAMPLE_AEDAT4, out, compression=compression), out=None)
    streams = aedat.Decoder(str(out)).id_to_stream()
    assert sorted(s["type"] for s in streams.values()) == ["events", "frame", "imus", "triggers"]
    n, frames = 0, []
    for packet in aedat.Decoder(str(out)):
        if "events" in packet:
            n += len(packet["events"])
        elif "frame" in packet:
            frames.append(packet["frame"])
    assert n == len(want["events"])
    assert [(f["exposure_begin_t"], f["exposure_end_t"]) for f in frames] == [
        (f.exposure_start_us, f.exposure_end_us) for f in want["frames"]
    ]
    assert all(f["format"] == "L" and f["pixels"].shape == (260, 346) for f in frames)


@pytest.mark.skipif(not SAMPLE_AEDAT4.is_file(), reason="the real DAVIS346 sample (../shared/data) is not here")
def test_aedat4_opens_in_inivation_dv_processing(tmp_path):
    dv = pytest.importorskip(
        "dv_processing", reason="iniVation's dv-processing is not installed (pip install 'necviz[dv]')"
    )
    want = _read_input(SAMPLE_AEDAT4)
    out = tmp_path / "sample.aedat4"
    export(ExportOptions(SAMPLE_AEDAT4, out), out=None)
    rec = dv.io.MonoCameraRecording(str(out))
    assert rec.getEventResolution() == (346, 260)
    assert rec.isEventStreamAvailable() and rec.isFrameStreamAvailable()
    assert rec.isImuStreamAvailable() and rec.isTriggerStreamAvailable()
    ts = []
    while (batch := rec.getNextEventBatch()) is not None:
        ts.append(batch.numpy()["timestamp"])
    np.testing.assert_array_equal(np.concatenate(ts), want["events"]["t"])
    frames = []
    while (f := rec.getNextFrame()) is not None:
        frames.append(f)
    assert len(frames) == len(want["frames"])
    for got, ref in zip(frames, want["frames"], strict=True):
        # dv-processing: a frame's timestamp is its exposure start, ``exposure`` its length
        assert got.timestamp == ref.exposure_start_us
        assert got.exposure.total_seconds() * 1e6 == pytest.approx(ref.exposure_us)
        np.testing.assert_array_equal(got.image.reshape(ref.image.shape), ref.image)
    imu = []
    while (b := rec.getNextImuBatch()) is not None:
        imu += [(s.timestamp, s.accelerometerX, s.gyroscopeZ) for s in b]
    assert [i[0] for i in imu] == want["imu"]["t"].tolist()
    np.testing.assert_allclose([i[1] for i in imu], want["imu"]["ax"], rtol=1e-6)
    trg = []
    while (b := rec.getNextTriggerBatch()) is not None:
        trg += [(t.timestamp, int(t.type)) for t in b]
    assert trg == list(zip(want["triggers"]["t"].tolist(), want["triggers"]["kind"].tolist(), strict=True))


def test_native_clip_keeps_commands_and_annotations(seeds, tmp_path):
    path = seeds["necviz:seed.necrec"]
    src = open_recording(path)
    commands, notes = list(src.commands), list(src.annotations)
    src.close()
    out = tmp_path / "clip.necrec"
    export(ExportOptions(path, out), out=None)
    back = open_recording(out)
    assert back.commands == commands and back.annotations == notes
    assert back.properties["exported_from"] == path.name  # the name, not the path as typed
    back.close()


def test_outputs_never_destroy_inputs_and_leave_nothing_on_failure(seeds, tmp_path, capsys):
    path = seeds["necviz:seed.necrec"]
    before = path.read_bytes()
    assert main(["export", str(path), str(path), "--force"]) == 2
    assert "is the input file" in capsys.readouterr().err
    assert path.read_bytes() == before
    out = tmp_path / "x.h5"
    out.write_bytes(b"keep me")
    assert main(["export", str(path), str(out)]) == 2
    assert "already exists" in capsys.readouterr().err and out.read_bytes() == b"keep me"
    assert main(["export", str(path), str(tmp_path / "x.mp4")]) == 2
    assert ".aedat4" in capsys.readouterr().err
    # a range past the end: an error, and no file
    assert main(["export", str(path), str(tmp_path / "late.npz"), "--start", "500"]) == 2
    assert "nothing" in capsys.readouterr().err
    # a damaged input: the error, and nothing half-written under the name nor beside it
    bad = tmp_path / "bad.necrec"
    data = bytearray(before)
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError):
        export(ExportOptions(bad, tmp_path / "bad.aedat4"), out=None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.necrec", "x.h5"]


def test_export_replaces_with_force_and_reports(seeds, tmp_path, capsys):
    path = seeds["necviz:seed.necrec"]
    out = tmp_path / "x.npz"
    out.write_bytes(b"old")
    assert main(["export", str(path), str(out), "--force"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert len(load_npz(out)["events"]) == len(_read_input(path)["events"])


def test_empty_range_is_refused_before_writing(seeds, tmp_path):
    with pytest.raises(ParameterError, match="must come after"):
        export(ExportOptions(seeds["necviz:seed.necrec"], tmp_path / "a.h5", start_s=1.0, end_s=0.5), out=None)
    assert not (tmp_path / "a.h5").exists()


def test_tonic_and_faery_layouts():
    ev = np.zeros(4, EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = [5, 6, 6, 9], [1, 345, 0, 7], [0, 259, 3, 2], [1, -1, -1, 1]
    tn = to_tonic(ev)
    assert tn.dtype == TONIC_DTYPE and tn.dtype.names == ("x", "y", "p", "t")
    assert tn["p"].tolist() == [True, False, False, True] and tn["x"].tolist() == [1, 345, 0, 7]
    fa = to_faery(ev)
    assert fa.dtype == FAERY_DTYPE and fa["on"].tolist() == [True, False, False, True]
    np.testing.assert_array_equal(from_tonic(tn), ev)
    np.testing.assert_array_equal(from_faery(fa), ev)
    # tonic's 0/1 integer polarity reads the same as its booleans
    ints = np.zeros(4, [("x", int), ("y", int), ("t", int), ("p", int)])
    for k in "xyt":
        ints[k] = tn[k]
    ints["p"] = tn["p"]
    np.testing.assert_array_equal(from_tonic(ints), ev)
    with pytest.raises(ValueError, match="unsigned"):
        to_faery(np.array([(-1, 0, 0, 1)], EVENT_DTYPE))
    with pytest.raises(ValueError, match="fields"):
        to_tonic(np.zeros(3))


@pytest.mark.skipif(not SAMPLE_AEDAT4.is_file(), reason="the real DAVIS346 sample (../shared/data) is not here")
def test_aedat4_keeps_the_camera_name_and_declares_only_its_streams(tmp_path):
    """The sample's camera is DAVIS346_00000002 (its XML ``source``): the export keeps it; a cut that holds
    some kinds of data only gives a file that declares those streams only."""
    import re

    import aedat

    from necviz.drivers.recordings.aedat4 import Aedat4Recording

    def sources(path):
        return set(re.findall(r'key="source"[^>]*>([^<]*)<', Aedat4Recording(path).description))

    assert sources(SAMPLE_AEDAT4) == {"DAVIS346_00000002"}
    out = tmp_path / "sample.aedat4"
    export(ExportOptions(SAMPLE_AEDAT4, out), out=None)
    assert sources(out) == {"DAVIS346_00000002"}
    again = tmp_path / "again.aedat4"
    export(ExportOptions(tmp_path / "sample.aedat4", tmp_path / "via.necrec"), out=None)
    export(ExportOptions(tmp_path / "via.necrec", again), out=None)  # through necviz's own format
    assert sources(again) == {"DAVIS346_00000002"}
    events_only = tmp_path / "events.aedat4"
    export(ExportOptions(SAMPLE_AEDAT4, events_only, start_s=0.0, end_s=0.001), out=None)
    kinds = sorted(s["type"] for s in aedat.Decoder(str(events_only)).id_to_stream().values())
    got = _read_output(events_only)
    assert kinds == sorted(
        k
        for k, n in (
            ("events", len(got["events"])),
            ("frame", len(got["frames"])),
            ("imus", len(got["imu"])),
            ("triggers", len(got["triggers"])),
        )
        if n
    ), kinds
    assert 0 < len(kinds) < 4  # the first millisecond does not hold all four kinds: fewer declared


def test_compression_is_refused_where_the_format_has_its_own(seeds, tmp_path, capsys):
    src = next(iter(seeds.values()))
    for suffix in (".npz", ".h5"):
        assert main(["export", str(src), str(tmp_path / f"x{suffix}"), "--compression", "zstd"]) == 2
        assert "--compression applies to .aedat4 and .necrec" in capsys.readouterr().err
        assert not (tmp_path / f"x{suffix}").exists()


def test_export_reads_a_named_pipe_with_the_flag_it_suggests(seeds, tmp_path, capsys):
    import os
    import threading

    src = seeds["necviz:seed.necrec"]
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    assert main(["export", str(fifo), str(tmp_path / "a.npz")]) == 2
    err = capsys.readouterr().err
    assert "--pipe-timeout" in err and not (tmp_path / "a.npz").exists()

    def feed():
        with open(fifo, "wb") as f:
            f.write(src.read_bytes())

    t = threading.Thread(target=feed)
    t.start()
    assert main(["export", str(fifo), str(tmp_path / "b.npz"), "--pipe-timeout", "10"]) == 0
    t.join(10)
    want = _read_input(src)
    np.testing.assert_array_equal(load_npz(tmp_path / "b.npz")["events"], want["events"])
