"""Outputs never destroy inputs or earlier work: refused before anything starts, written atomically."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest
from conftest import SHARED_DATA

from necviz.commands.cli import main
from necviz.core.errors import ParameterError
from necviz.outputs import atomic_write, check_output, commit_recording, recording_target, write_json

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

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
    assert check_output(tmp_path / "no" / "b.json", "--json") == tmp_path / "no" / "b.json"  # folder created
    (tmp_path / "file").write_text("x")
    with pytest.raises(ParameterError, match="Not a directory"):  # a file where its folder should be
        check_output(tmp_path / "file" / "b.json", "--json")
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


# -- issue 23: no output is an input, even with --force; nothing half-written is left -------------
PROFILE = Path(__file__).resolve().parents[1] / "necviz" / "profiles" / "davis346-sim.json"


def _same_name(path, how, tmp_path):
    """Another name for ``path``: itself, a symbolic link to it or a hard link."""
    if how == "path":
        return path
    other = tmp_path / f"{how}-{path.stem}.json"
    (os.symlink if how == "symlink" else os.link)(path, other)
    return other


@pytest.mark.parametrize("how", ["path", "symlink", "hardlink"])
@pytest.mark.parametrize("case", ["replay-profile", "compare-profile", "compare-scenario", "demo-tune", "calibrate"])
def test_no_output_may_be_an_input_even_with_force(case, how, recording, tmp_path, capsys):
    profile = tmp_path / "prof.json"
    shutil.copy(PROFILE, profile)
    scenario = tmp_path / "s.toml"
    scenario.write_text('name = "tunnel_exit"\nduration_s = 0.1\n')
    tune = tmp_path / "tune.json"
    tune.write_text("goal = 100\n")
    if case == "replay-profile":
        victim = profile
        argv = ["replay", str(recording), "--profile", str(profile), "--save", str(tmp_path / "r.rrd"), "--json"]
    elif case == "compare-profile":
        victim = profile
        argv = ["compare", "--duration", "0.1", "--no-sift", "--profile", str(profile), "--json"]
    elif case == "compare-scenario":
        victim = scenario
        argv = ["compare", "--scenario", str(scenario), "--no-sift", "--json"]
    elif case == "demo-tune":
        victim = tune
        argv = ["demo", "--duration", "0.1", "--tune-file", str(tune), "--no-prompt", "--save", str(tmp_path / "d.rrd")]
        argv += ["--record"]
        victim = tmp_path / "tune.necrec"
        victim.write_text("goal = 100\n")
        argv[argv.index(str(tune))] = str(victim)
    else:
        victim = profile
        argv = ["calibrate", "--sim", "calibration", "--profile", str(profile), "--out"]
    out = _same_name(victim, how, tmp_path)
    if case == "demo-tune" and how != "path":  # a .necrec name for the record flag's extension check
        renamed = out.with_suffix(".necrec")
        os.rename(out, renamed)
        out = renamed
    argv += [str(out), "--force"]
    before, mode = digest(victim), victim.stat().st_mode
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and "\n" not in err and "choose another name" in err, err
    assert digest(victim) == before and victim.stat().st_mode == mode
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*"))


def test_check_not_input_api(tmp_path):
    from necviz.outputs import check_not_input

    a = tmp_path / "a.bin"
    a.write_bytes(b"x")
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "events.txt").write_text("0 1 2 1\n")
    check_not_input({"--out": tmp_path / "b.bin"}, [a, folder])  # different files: fine
    check_not_input({"--out": None}, [a])
    with pytest.raises(ParameterError, match="is the input file"):
        check_not_input({"--out": tmp_path / "x" / ".." / "a.bin"}, [a])
    with pytest.raises(ParameterError, match="is a file of the input folder"):
        check_not_input({"--json": folder / "events.txt"}, [folder])
    check_not_input({"--json": folder / "summary.json"}, [folder])  # a new file beside the recording's
    with pytest.raises(ParameterError, match="the profile file"):
        check_not_input([a], {"profile": a})


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_a_replaced_output_gets_the_permissions_of_a_new_file(mask, tmp_path):
    old = tmp_path / "r.json"
    old.write_text("{}")
    os.chmod(old, 0o600)
    prev = os.umask(mask)
    try:
        write_json(old, {"v": 2})
        fresh = tmp_path / "fresh.json"
        write_json(fresh, {"v": 1})
        with open(tmp_path / "by-open.json", "w") as f:  # what Python's own open gives
            f.write("{}")
    finally:
        os.umask(prev)
    expected = (tmp_path / "by-open.json").stat().st_mode & 0o777
    assert expected == 0o666 & ~mask
    assert old.stat().st_mode & 0o777 == expected and fresh.stat().st_mode & 0o777 == expected
    assert json.loads(old.read_text()) == {"v": 2}


def _fail_writes_to(monkeypatch, suffix, after_bytes=0, err=errno.ENOSPC):
    """``os.write`` fails with ``err`` on files named ``*suffix`` once ``after_bytes`` went through."""
    real = os.write
    written = {}

    def write(fd, data):
        try:
            name = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            name = ""
        if name.endswith(suffix):
            if written.get(name, 0) + len(data) > after_bytes:
                raise OSError(err, os.strerror(err))
            written[name] = written.get(name, 0) + len(data)
        return real(fd, data)

    monkeypatch.setattr(os, "write", write)


def test_a_full_disk_on_json_leaves_nothing_and_says_so(recording, tmp_path, capsys, monkeypatch):
    real = os.fsync

    def fsync(fd):
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".tmp"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    old = tmp_path / "old.json"
    old.write_text('{"earlier": true}')
    for target, extra in ((tmp_path / "new.json", []), (old, ["--force"])):
        before = list(tmp_path.iterdir())
        assert main(["info", str(recording), "--json", str(target), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("necviz: error: --json: cannot write") and "No space left on device" in err
        assert "nothing was written" in err and "\n" not in err
        assert sorted(tmp_path.iterdir()) == sorted(before)  # no new file, no hidden temporary
    assert old.read_text() == '{"earlier": true}'


def test_a_full_disk_while_recording_removes_the_recording_and_keeps_the_old_one(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("NECVIZ_DISK_RESERVE_MB", "0")
    _fail_writes_to(monkeypatch, ".necrec", after_bytes=200_000)
    old = tmp_path / "run.necrec"
    old.write_bytes(b"an earlier recording")
    argv = ["demo", "--duration", "0.5", "--controllers", "nec", "--no-prompt", "--save", str(tmp_path / "d.rrd")]
    assert main([*argv, "--record", str(tmp_path / "new.necrec")]) == 2
    err = capsys.readouterr().err.strip()
    assert "No space left on device" in err and "nothing was written" in err and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.necrec"]  # neither new file, no partial
    assert main([*argv, "--record", str(old), "--force"]) == 2
    captured = capsys.readouterr()
    assert "is unchanged" in captured.err and "recorded to" not in captured.out
    assert old.read_bytes() == b"an earlier recording" and sorted(p.name for p in tmp_path.iterdir()) == ["run.necrec"]


def test_live_keeps_what_it_recorded_before_a_full_disk_and_does_not_claim_success(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("NECVIZ_DISK_RESERVE_MB", "0")
    _fail_writes_to(monkeypatch, ".necrec", after_bytes=2_000_000)
    rec = tmp_path / "l.necrec"
    argv = ["live", "--device", "emulated", "--duration", "4", "--no-prompt", "--record", str(rec)]
    assert main([*argv, "--save", str(tmp_path / "l.rrd")]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "No space left on device" in err and "kept in" in err and "\n" not in err, err
    assert "recorded to" not in captured.out
    from necviz.drivers.recordings import open_recording

    frames = [p for p in open_recording(rec) if type(p).__name__ == "Frame"]  # readable up to the failure
    assert frames and rec.stat().st_size <= 2_000_000


def test_the_disk_guard_stops_a_run_before_the_disk_is_full(tmp_path, capsys, monkeypatch):
    """Free space falling under the reserve mid-run stops it cleanly; a demo's files are then removed."""
    import necviz.outputs as outputs

    calls = {"n": 0}

    def free(path):
        calls["n"] += 1
        return 10 << 30 if calls["n"] <= 3 else 1 << 20  # plenty at the start, then 1 MB

    monkeypatch.setattr(outputs, "free_bytes", free)
    out = tmp_path / "g.rrd"
    code = main(["demo", "--duration", "3", "--controllers", "nec", "--speed", "1", "--no-prompt", "--save", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "nearly full" in err and "nothing was written" in err and "\n" not in err, err
    assert not list(tmp_path.iterdir())


def test_a_recording_cut_by_the_file_size_limit_is_one_line_and_leaves_nothing(tmp_path):
    """The real thing, in a separate process: Rerun's own writer hits ``ulimit -f`` (as a full disk)."""
    import resource
    import subprocess
    import sys
    import time

    argv = [sys.executable, "-m", "necviz", "demo", "--duration", "0.5", "--controllers", "nec", "--no-prompt"]
    env = {**os.environ, "NECVIZ_DISK_RESERVE_MB": "0", "PYTHONDONTWRITEBYTECODE": "1"}
    warm = subprocess.run([*argv, "--save", str(tmp_path / "warm.rrd")], capture_output=True, env=env, cwd=tmp_path)
    assert warm.returncode == 0 and (tmp_path / "warm.rrd").stat().st_size > 150_000  # bigger than the limit
    (tmp_path / "warm.rrd").unlink()

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))

    t0 = time.monotonic()
    proc = subprocess.run(
        [*argv, "--save", str(tmp_path / "z.rrd")],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        preexec_fn=limit,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert err.startswith("necviz: error: cannot write") and "nothing was written" in err and "\n" not in err, err
    assert not list(tmp_path.iterdir()) and time.monotonic() - t0 < 60


def test_streamed_output_commit_and_discard(tmp_path):
    from necviz.outputs import StreamedOutput

    new = StreamedOutput(tmp_path / "a.necrec")
    assert new.target == tmp_path / "a.necrec" and new.target.exists()
    assert new.discard() == f"nothing was written to {tmp_path / 'a.necrec'}" and not list(tmp_path.iterdir())
    old = tmp_path / "b.necrec"
    old.write_bytes(b"old")
    repl = StreamedOutput(old)
    repl.target.write_bytes(b"new")
    assert repl.discard().endswith("is unchanged") and old.read_bytes() == b"old" and len(list(tmp_path.iterdir())) == 1
    kept = StreamedOutput(old, keep_partial=True)
    kept.target.write_bytes(b"camera data")
    assert "so far" in kept.discard() and old.read_bytes() == b"camera data" and len(list(tmp_path.iterdir())) == 1
