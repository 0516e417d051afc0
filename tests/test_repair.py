"""A recording cut short by SIGKILL is still readable as a stream, and ``necviz repair`` makes it whole."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from rerun.chunk import RrdReader

from necviz.commands.cli import main


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
    with pytest.warns(Warning, match="no footer"):
        reader = RrdReader(str(rrd))
    with pytest.raises(Exception, match="without footer"):
        reader.store()
    streamed = sum(1 for _ in reader.stream().to_chunks())
    assert streamed > 10  # everything logged before the kill is there
    before = rrd.read_bytes()
    assert main(["repair", str(rrd)]) == 0
    fixed = tmp_path / "cut.repaired.rrd"
    assert rrd.read_bytes() == before  # the input is never touched
    RrdReader(str(fixed)).store()  # indexable again
    assert f"rerun {fixed}" in capsys.readouterr().out
    assert main(["repair", str(rrd)]) == 2  # the copy exists: refused without --force
    assert main(["repair", str(tmp_path / "nope.rrd")]) == 2
