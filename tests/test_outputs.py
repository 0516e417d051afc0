"""Outputs never destroy inputs or earlier work: refused before anything starts, written atomically."""

from __future__ import annotations

import hashlib
import os
import shutil

import pytest
from conftest import SHARED_DATA

from necviz.commands.cli import main
from necviz.core.errors import ParameterError
from necviz.outputs import atomic_write, check_output, commit_recording, recording_target, write_json

SAMPLE = SHARED_DATA / "davis346_sample.aedat4"


def digest(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def recording(tmp_path):
    """An input recording: the real sample if present, else a small native one."""
    if SAMPLE.exists():
        dst = tmp_path / "in.aedat4"
        shutil.copy(SAMPLE, dst)
        return dst
    from test_pipeline import SENSOR, stream

    from necviz.drivers.recordings import Recorder

    dst = tmp_path / "in.necrec"
    with Recorder(dst, sensor=SENSOR, properties={}) as rec:
        for p in stream(n_frames=3):
            rec.write(p)
    return dst


@pytest.mark.parametrize(
    "case", ["info-json", "replay-json", "live-record", "record-save", "replay-json-hardlink", "demo-save-existing"]
)
def test_outputs_that_would_destroy_a_file_are_refused_and_leave_it_byte_identical(case, recording, tmp_path, capsys):
    inp = str(recording)
    victim = recording
    if case == "info-json":
        argv = ["info", inp, "--json", inp]
    elif case == "replay-json":
        argv = ["replay", inp, "--json", inp, "--save", str(tmp_path / "r.rrd")]
    elif case == "replay-json-hardlink":
        link = tmp_path / "link.json"
        os.link(recording, link)  # another name for the same file
        argv = ["replay", inp, "--json", str(link), "--force", "--save", str(tmp_path / "r.rrd")]
    elif case == "live-record":
        argv = [
            "live",
            "--device",
            "emulated",
            "--duration",
            "0.2",
            "--record",
            inp,
            "--no-prompt",
            "--save",
            str(tmp_path / "l.rrd"),
        ]
    elif case == "record-save":
        victim = tmp_path / "x.necrec"
        victim.write_bytes(b"earlier work")
        argv = ["demo", "--duration", "0.1", "--record", str(victim), "--save", str(victim), "--force", "--no-prompt"]
    else:
        victim = tmp_path / "old.rrd"
        victim.write_bytes(b"an earlier recording")
        argv = ["demo", "--duration", "0.1", "--save", str(victim), "--no-prompt"]
    before = digest(victim)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and "\n" not in err, err
    assert digest(victim) == before
    assert not (tmp_path / "r.rrd").exists() and not (tmp_path / "l.rrd").exists()


def test_force_replaces_an_existing_output_only_when_the_run_succeeds(tmp_path):
    old = tmp_path / "old.rrd"
    old.write_bytes(b"an earlier recording")
    assert (
        main(["demo", "--duration", "0.1", "--controllers", "nec", "--save", str(old), "--force", "--no-prompt"]) == 0
    )
    assert old.stat().st_size > 10_000 and not list(tmp_path.glob(".old*"))  # replaced; no temporary file left


def test_record_needs_the_native_extension(tmp_path, capsys):
    assert (
        main(
            [
                "demo",
                "--duration",
                "0.1",
                "--record",
                str(tmp_path / "r.aedat4"),
                "--no-prompt",
                "--save",
                str(tmp_path / "d.rrd"),
            ]
        )
        == 2
    )
    assert "--record expects a .necrec file name" in capsys.readouterr().err


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "result.json"
    write_json(target, {"v": 1})
    with pytest.raises(RuntimeError):
        with atomic_write(target) as f:
            f.write('{"v": 2, "half": ')
            raise RuntimeError("disk full (simulated)")
    assert target.read_text().strip() == '{\n  "v": 1\n}' and len(list(tmp_path.iterdir())) == 1


def test_check_output_rules(tmp_path):
    existing = tmp_path / "a.json"
    existing.write_text("{}")
    with pytest.raises(ParameterError, match="already exists; pass --force"):
        check_output(existing, "--json")
    assert check_output(existing, "--json", force=True) == existing
    with pytest.raises(ParameterError, match="is the input file"):
        check_output(tmp_path / "." / "a.json", "--json", inputs=[existing], force=True)
    with pytest.raises(ParameterError, match="does not exist"):
        check_output(tmp_path / "no" / "b.json", "--json")
    with pytest.raises(ParameterError, match="is a folder"):
        check_output(tmp_path, "--json")
    with pytest.raises(ParameterError, match="expects a .rrd"):
        check_output(tmp_path / "b.txt", "--save", suffixes=(".rrd",))


def test_a_recording_replacing_a_file_goes_beside_it_until_complete(tmp_path):
    new = recording_target(tmp_path / "fresh.necrec")
    assert new == tmp_path / "fresh.necrec" and new.exists()  # a new name is claimed at once
    old = tmp_path / "old.necrec"
    old.write_bytes(b"keep me until the new one is complete")
    target = recording_target(old)
    assert target != old and target.parent == old.parent and old.read_bytes().startswith(b"keep me")
    target.write_bytes(b"new")
    commit_recording(target, old)
    assert old.read_bytes() == b"new" and not target.exists()
