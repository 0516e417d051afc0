"""Every script in examples/ runs (as a user would: a subprocess in a scratch directory) and prints
what it claims."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SHARED_DATA

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SAMPLE = SHARED_DATA / "davis346_sample.aedat4"


def run_example(name: str, *args: str, cwd: Path, expect_rc: int = 0) -> str:
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args], cwd=cwd, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == expect_rc, f"{name} exited {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout + proc.stderr


TESTED = {
    "offline_nec.py",
    "ptedi_ramp.py",
    "custom_scenario.py",
    "custom_controller.py",
    "replay_summary.py",
    "demo_from_python.py",
}


def test_every_example_is_listed_and_runs(tmp_path):
    names = {p.name for p in EXAMPLES.glob("*.py")}
    assert TESTED <= names
    readme = (EXAMPLES / "README.md").read_text()
    assert not [n for n in names if n not in readme], "list every example in examples/README.md"
    for name in sorted(names - TESTED):  # examples added without a test of their own: at least they run
        assert run_example(name, cwd=tmp_path).strip()


def test_offline_nec(tmp_path):
    out = run_example("offline_nec.py", cwd=tmp_path)
    rows = [line.split() for line in out.splitlines() if re.match(r"\s+\d+\s", line)]
    assert len(rows) == 6
    # after the step NEC's frames are not blown out while the stale exposure's are
    assert all(float(r[4].rstrip("%")) < 50 and float(r[5].rstrip("%")) > 50 for r in rows[3:])


def test_ptedi_ramp_stays_within_half_a_threshold(tmp_path):
    out = run_example("ptedi_ramp.py", "--plot", "ramp.png", cwd=tmp_path)
    m = re.search(r"max \|error\| over (\d+) predictions: ([\d.]+) ln \(frames alone: ([\d.]+) ln\)", out)
    assert m, out
    assert int(m[1]) > 50
    assert float(m[2]) < 0.26 / 2  # c/2
    assert float(m[2]) < float(m[3])  # events beat holding the last frame's value
    assert (tmp_path / "ramp.png").stat().st_size > 1000


def test_custom_scenario(tmp_path):
    out = run_example("custom_scenario.py", "--duration-s", "0.6", cwd=tmp_path)
    sat = re.search(r"saturated frames: (\d+) of (\d+)", out)
    trace = re.search(r"initial (\d+) µs, min (\d+) µs, max (\d+) µs \(gain up to ([\d.]+)\), final (\d+) µs", out)
    assert sat and trace, out
    assert 0 <= int(sat[1]) <= int(sat[2]) and int(sat[2]) >= 25
    initial, _, longest, gain, _ = (float(v) for v in trace.groups())
    # the lamp went off: NEC lengthened the exposure (and added gain) by well over e^2
    assert longest * gain > 7 * initial
    # the lamp dims by 3 ln: the exposure-gain product settles 3 ln above where it had settled with the lamp
    # on (not the initial guess, which NEC first corrects towards its goal), then back there
    settled = {m[1]: float(m[2]) for m in re.finditer(r"^(lamp on|lamp off|on again) .* ([+-]\d+\.\d\d)$", out, re.M)}
    on = settled["lamp on"]
    assert abs(settled["lamp off"] - on - 3.0) < 0.3 and abs(settled["on again"] - on) < 0.3, out


def test_custom_controller_table_lists_three_controllers(tmp_path):
    out = run_example("custom_controller.py", "--duration-s", "0.6", cwd=tmp_path)
    rows = {
        line.split()[0]: line.split()[1:]
        for line in out.splitlines()
        if line.split() and line.split()[0] in ("nec", "navid", "meanprop")
    }
    assert set(rows) == {"nec", "navid", "meanprop"}, out
    for cells in rows.values():
        assert int(cells[0]) >= 25  # frames
        assert 0 <= int(cells[1]) <= int(cells[0])  # saturated frames


def test_custom_controller_registered_in_compare(tmp_path):
    out = run_example("custom_controller.py", "--via-compare", "--duration-s", "0.4", cwd=tmp_path)
    rows = [line.split()[0] for line in out.splitlines()[-3:]]
    assert rows == ["nec", "navid", "meanprop"], out


def test_custom_controller_rejects_bad_arguments(tmp_path):
    out = run_example("custom_controller.py", "--k", "2", cwd=tmp_path, expect_rc=2)
    assert "--k" in out and "Traceback" not in out


@pytest.mark.skipif(not SAMPLE.is_file(), reason=f"sample recording {SAMPLE} not present (shared data folder)")
def test_replay_summary(tmp_path):
    out = run_example("replay_summary.py", str(SAMPLE), cwd=tmp_path)
    diffs = [float(v) for v in re.findall(r"^\s+\d+ .* ([+-]\d\.\d{3})\s+[\d.]+%$", out, re.M)]
    assert len(diffs) == 3, out  # frames 1..3 have a prediction from the frame before
    assert max(abs(d) for d in diffs) < 0.13
    assert "final prediction" in out


def test_replay_summary_on_a_recording_a_user_can_make(tmp_path):
    """examples/README.md's command, on the recording its line says how to make (no camera, no shared data)."""
    from necviz.commands.cli import main

    rec = tmp_path / "run.necrec"
    argv = ["live", "--device", "emulated", "--duration", "0.5", "--record", str(rec)]
    assert main([*argv, "--save", str(tmp_path / "run.rrd"), "--no-prompt"]) == 0
    readme = (EXAMPLES / "README.md").read_text()
    assert "necviz live --device emulated --duration 2 --record run.necrec" in readme
    assert "python examples/replay_summary.py run.necrec" in readme
    out = run_example("replay_summary.py", "run.necrec", cwd=tmp_path)
    rows = re.findall(r"^\s+\d+ .* ([+-]\d\.\d{3})\s+[\d.]+%$", out, re.M)
    assert len(rows) >= 10 and "final prediction" in out, out


def test_replay_summary_missing_file(tmp_path):
    out = run_example("replay_summary.py", str(tmp_path / "absent.aedat4"), cwd=tmp_path, expect_rc=1)
    assert "not found" in out and "Traceback" not in out


def test_demo_from_python(tmp_path):
    out = run_example(
        "demo_from_python.py", "--scenario", "flicker", "--duration-s", "0.3", "--out", "py.rrd", cwd=tmp_path
    )
    lanes = re.findall(r"^\s+(nec|navid|fixed)\s+(\d+) frames", out, re.M)
    assert [n for n, _ in lanes] == ["nec", "navid", "fixed"] and all(int(f) >= 14 for _, f in lanes)
    assert (tmp_path / "py.rrd").stat().st_size > 10_000 and "rerun py.rrd" in out
    bad = run_example("demo_from_python.py", "--scenario", "moon", cwd=tmp_path, expect_rc=1)
    assert "error: --scenario: 'moon' is neither a preset" in bad and "Traceback" not in bad
