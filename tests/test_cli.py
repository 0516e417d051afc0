"""The necviz command: version, info, the estimator benchmark's JSON, and one-line errors."""

import json
import subprocess
import sys

import pytest

from necviz import __version__
from necviz.commands.cli import main

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


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
    from necviz.core.control import CONTROLLERS
    from necviz.dashboard.viewer_flags import LAYOUT_NAMES as VIEWER_LAYOUTS
    from necviz.drivers.recordings import FORMATS as READER_FORMATS
    from necviz.drivers.sim.scenes import SCENARIOS
    from necviz.names import CONTROLLER_NAMES, FORMATS, LAYOUT_NAMES, SCENARIO_NAMES
    from necviz.options import LAYOUT_NAMES as OPTION_LAYOUTS

    assert sorted(CONTROLLER_NAMES) == sorted(CONTROLLERS)
    assert sorted(SCENARIO_NAMES) == sorted(SCENARIOS)
    assert LAYOUT_NAMES == VIEWER_LAYOUTS == OPTION_LAYOUTS
    assert FORMATS == READER_FORMATS  # --format's choices are the readers' formats


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


# -- issue 23: every numeric flag refuses NaN, infinities, garbage and values out of its range -----
def _numeric_flags():
    import argparse

    from necviz.commands.cli import build_parser

    out, plain = [], []

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, (*prefix, name))
            elif action.option_strings:
                if getattr(action.type, "necviz_rule", None) is not None:
                    out.append((prefix, action.option_strings[0], action.type.necviz_rule))
                elif action.type in (int, float):
                    plain.append((prefix, action.option_strings[0]))

    walk(build_parser(), ())
    return out, plain


def test_every_numeric_flag_is_checked_through_the_one_table():
    flags, plain = _numeric_flags()
    assert plain == []  # no flag converts with a bare int() or float()
    assert len(flags) > 40
    assert {f for _, f, _ in flags} >= {"--exposure-us", "--duration", "--seed", "--event-window-ms", "--workers"}


def test_every_numeric_flag_refuses_nan_infinity_garbage_and_out_of_range(capsys):
    from necviz.flags import NUMBER_FLAGS

    flags, _ = _numeric_flags()
    for prefix, flag, (name, command) in flags:
        rule = NUMBER_FLAGS.get(f"{command} {name}") or NUMBER_FLAGS[name]
        bad = ["nan", "inf", "-inf", "banana", "1e400", ""]
        if rule.lo is not None:
            bad.append(str(rule.lo - 1) if not rule.lo_open else str(rule.lo))  # below, or 0 where 0 means nothing
        if rule.hi is not None:
            bad.append(str(rule.hi * 2 + 1))
        if rule.integer:
            bad.append("1.5")
        for value in bad:
            code = main([*prefix, f"{flag}={value}"])
            err = capsys.readouterr().err.strip()
            assert code == 2, (prefix, flag, value)
            assert err.startswith("necviz: error:") and "\n" not in err and flag in err, (prefix, flag, value, err)


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["demo", "--speed", "0"], "--speed must be 'max'"),
        (["demo", "--speed", "nan"], "--speed"),
        (["demo", "--memory-limit", "banana"], "--memory-limit expects"),
        (["info", "--exposure-us", "nan", "x.aedat4"], "--exposure-us must be finite"),
        (["replay", "x.aedat4", "--end", "0"], "--end = 0 is out of range"),
    ],
)
def test_accepted_nonsense_is_refused(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and needle in err and "\n" not in err, err


def test_numba_cache_falls_back_to_a_writable_temporary_folder(monkeypatch, tmp_path):
    """Neither the package's __pycache__ nor ~/.cache/numba writable: the cache goes to a temporary folder."""
    import os
    import tempfile

    import numba

    import necviz

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)  # restored after the test
    monkeypatch.setattr(necviz.os, "access", lambda *a, **k: False)
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    necviz._numba_cache_fallback()
    folder = tmp_path / f"necviz-numba-{os.getuid()}"
    assert os.environ["NUMBA_CACHE_DIR"] == str(folder) and folder.is_dir()
    assert numba.config.CACHE_DIR == str(folder)  # numba was imported already: its config follows


def test_version_and_a_numba_kernel_work_with_an_unwritable_home():
    """As a user who can write neither the installed package nor the home folder (here: nobody)."""
    import os
    import shutil

    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to run as an unprivileged user")
    env = {"HOME": "/nonexistent", "PATH": "/usr/bin:/bin"}
    for args in (["--version"], ["info"]):
        r = subprocess.run(
            ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-m", "necviz", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=300,
        )
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-1000:]
