"""A recording cut short by SIGKILL is still readable as a stream, and ``necviz repair`` makes it whole."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from rerun.chunk import RrdReader

from necviz.commands.cli import main
from necviz.commands.repair import repair

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


def test_a_killed_run_is_repaired_into_a_copy(tmp_path, capsys):
    rrd = tmp_path / "cut.rrd"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "necviz",
            "demo",
            "--duration",
            "30",
            "--controllers",
            "nec,fixed",
            "--save",
            str(rrd),
            "--speed",
            "1",
            "--no-prompt",
        ],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=open(tmp_path / "stderr.txt", "w"),  # noqa: SIM115 - closed with the process
    )
    deadline = time.time() + 120
    while time.time() < deadline and (not rrd.exists() or rrd.stat().st_size < 200_000):
        time.sleep(0.2)
    still_running = proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    assert still_running, f"the demo ended before it was killed: {(tmp_path / 'stderr.txt').read_text()[-2000:]}"
    # The kill leaves the file without its footer, and possibly cut inside a message (the writer
    # flushes in blocks): either way the indexing reader refuses it.
    with pytest.warns(Warning, match="no footer"):
        reader = RrdReader(str(rrd))
    with pytest.raises(Exception, match="without footer|exceeds file size"):
        reader.store()
    before = rrd.read_bytes()
    assert main(["repair", str(rrd)]) == 0
    fixed = tmp_path / "cut.repaired.rrd"
    assert rrd.read_bytes() == before  # the input is never touched
    RrdReader(str(fixed)).store()  # indexable again
    assert sum(1 for _ in RrdReader(str(fixed)).stream().to_chunks()) > 10  # what was logged before the kill
    assert f"rerun {fixed}" in capsys.readouterr().out
    assert main(["repair", str(rrd)]) == 2  # the copy exists: refused without --force
    assert main(["repair", str(tmp_path / "nope.rrd")]) == 2


def test_a_recording_cut_inside_a_message_is_repaired(tmp_path):
    """A cut in the middle of a message (not only a missing footer) keeps everything before it."""
    whole = tmp_path / "whole.rrd"
    assert main(["demo", "--duration", "0.3", "--controllers", "fixed", "--save", str(whole), "--no-prompt"]) == 0
    data = whole.read_bytes()
    chunks_whole = sum(1 for _ in RrdReader(str(whole)).stream().to_chunks())
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.warns(Warning, match="no footer"):
        reader = RrdReader(str(cut))
    with pytest.raises(Exception, match="without footer|exceeds file size"):
        reader.store()
    fixed = repair(cut)
    chunks_fixed = sum(1 for _ in RrdReader(str(fixed)).stream().to_chunks())
    assert 0 < chunks_fixed < chunks_whole  # the part before the cut, and not more
