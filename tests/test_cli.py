"""The necviz command: version, info, the estimator benchmark's JSON, and one-line errors."""

import json
import subprocess
import sys

import pytest

from necviz import __version__
from necviz.commands.cli import main


def test_version_and_module_entry_point():
    out = subprocess.run([sys.executable, "-m", "necviz", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"necviz {__version__}"


# What the command line must not load before a command runs (a second and more of start-up).
HEAVY = ("numpy", "numba", "scipy", "rerun", "cv2", "necviz.core.control", "necviz.drivers.sim", "necviz.core.ptedi")
_PROBE = """
import contextlib, io, json, sys
from necviz.commands.cli import main
with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.redirect_stderr(io.StringIO()) as err:
    try:
        rc = main(sys.argv[1:])
    except SystemExit as e:
        rc = e.code
print(json.dumps({"rc": rc, "modules": sorted(sys.modules), "out": out.getvalue(), "err": err.getvalue()}))
"""


@pytest.mark.parametrize(
    "argv, rc",
    [
        (["--version"], 0),
        (["--help"], 0),
        (["demo", "--help"], 0),
        (["calibrate", "--help"], 0),
        (["sweep", "run", "--help"], 0),
        (["demo", "--bogus"], 2),  # argument errors
        (["compare", "--controllers", "nec,nope"], 2),
        (["live", "--controller", "nope"], 2),
        (["replay"], 2),
    ],
)
def test_version_help_and_argument_errors_import_nothing_heavy(argv, rc):
    """Start-up: --version, --help and a mistyped flag answer without NumPy, Numba, Rerun or the controllers
    (asserted on the modules a fresh interpreter holds afterwards, not on a timing)."""
    got = json.loads(subprocess.run([sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True).stdout)
    assert got["rc"] == rc, got["err"]
    loaded = [m for m in got["modules"] if any(m == h or m.startswith(h + ".") for h in HEAVY)]
    assert loaded == [], f"{argv} imported {loaded[:5]}"
    if rc == 2:
        assert "error:" in got["err"]
    if argv == ["--help"]:
        assert "demo" in got["out"] and "calibrate" in got["out"]


def test_the_help_names_are_the_registered_ones():
    """The constants the parser shows (so it need not import the registries) are the registries' names."""
    from necviz.commands.cli import CONTROLLER_NAMES, LAYOUT_NAMES, SCENARIO_NAMES
    from necviz.core.control import CONTROLLERS
    from necviz.dashboard.viewer_flags import LAYOUT_NAMES as VIEWER_LAYOUTS
    from necviz.drivers.sim.scenes import SCENARIOS
    from necviz.options import LAYOUT_NAMES as OPTION_LAYOUTS

    assert sorted(CONTROLLER_NAMES) == sorted(CONTROLLERS)
    assert sorted(SCENARIO_NAMES) == sorted(SCENARIOS)
    assert LAYOUT_NAMES == VIEWER_LAYOUTS == OPTION_LAYOUTS


def test_info_lists_versions_threading_layer_and_controllers(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for needle in ("numba ", "rerun-sdk", "numba threading layer:", "controllers:", "nec"):
        assert needle in out
    layer = next(line for line in out.splitlines() if line.startswith("numba threading layer"))
    assert any(name in layer for name in ("omp", "tbb", "workqueue"))


def test_bench_estimators_writes_the_documented_json(tmp_path, capsys):
    path = tmp_path / "est.json"
    rc = main(
        [
            "bench",
            "estimators",
            "--events",
            "200000",
            "--duration",
            "0.2",
            "--fps",
            "50",
            "--repeats",
            "2",
            "--edi-samples",
            "8",
            "--json",
            str(path),
        ]
    )
    assert rc == 0
    data = json.loads(path.read_text())
    names = [r["method"] for r in data["rows"]]
    assert names == ["EDI", "mEDI", "Fast-EDI", "TEDI", "P-TEDI", "P-TEDI a=0", "floor"]
    for r in data["rows"]:
        assert r["mev_per_s"] > 0 and r["realtime_factor"] > 0
    # consistency of the two figures: rate / real-time factor = the stream's event rate
    span = data["stream"]["events_timed"] / data["stream"]["timed_span_s"] / 1e6
    for r in data["rows"]:
        assert r["mev_per_s"] / r["realtime_factor"] == pytest.approx(span, rel=1e-6)
    assert set(data["ratios"]) >= {"ptedi_over_fast_edi", "ptedi_over_floor"}
    table = capsys.readouterr().out
    assert "P-TEDI" in table and "floor" in table


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["bench", "estimators", "--events", "10"], "events >= 1000"),
        (["bench", "estimators", "--exposure-us", "30000", "--fps", "50"], "shorter than the frame period"),
    ],
)
def test_bad_parameters_give_one_line_errors(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and needle in err and "\n" not in err


def test_bench_sim_reports_speed_and_writes_json(tmp_path, capsys):
    path = tmp_path / "sim.json"
    assert main(["bench", "sim", "--duration", "0.1", "--cameras", "2", "--json", str(path)]) == 0
    data = json.loads(path.read_text())
    assert data["scenario"] == "tunnel_exit" and data["cameras"] == 2 and data["duration_s"] == 0.1
    assert data["realtime_factor"] > 0 and data["events"] > 0 and data["frames"] >= 8
    assert data["realtime_factor"] == pytest.approx(data["duration_s"] / data["wall_s"])
    out = capsys.readouterr().out
    assert "real-time factor" in out and "simulated" in out
    assert main(["bench", "sim", "--cameras", "0"]) == 2
