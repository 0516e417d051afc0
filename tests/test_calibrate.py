"""``necviz calibrate`` end to end: simulator data with known thresholds, the real DAVIS346 sample,
bad input, the profile file.

Truths used: the simulator's contrast thresholds (set to non-default values) and its camera
response (the DAVIS346-like curve it renders frames with); the real recording's residuals must be
finite and not worse after the fit than at its start (least squares never accepts a worse step).
"""

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from necviz.calibration import (
    DEFAULT_SELECTION,
    CalibrationOptions,
    CalibrationSimulation,
    CollectorOptions,
    PairCollector,
    calibrate_from_recordings,
    calibrate_from_simulation,
)
from necviz.commands.calibrate import COMMAND, parse_seeds
from necviz.core.camera_profile import CameraProfile
from necviz.core.crf import default_davis346
from necviz.core.errors import ParameterError, ProfileError
from necviz.core.event_model import TediParams
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.calibration_scene import CalibrationScene, CalibrationSceneOptions
from necviz.drivers.sim.dvs import DvsParams
from necviz.profiles import default_sim_profile, load_profile

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346_sample.aedat4"
SMALL = SensorGeometry(48, 36)
TRUE_ON, TRUE_OFF = 0.31, 0.19  # not the defaults (0.26 / 0.24), and ON != OFF


def cli(argv):
    p = argparse.ArgumentParser(prog="necviz")
    sub = p.add_subparsers(dest="command")
    COMMAND.register(sub)
    args = p.parse_args(["calibrate", *argv])
    return args.func(args)


@pytest.fixture(scope="module")
def sim_result():
    """Calibration scene, 48x36, seeds 0-2, 6 s each: thresholds only (compensation fixed at zero).

    The simulated DVS is the default one (mismatch, refractory period, bandwidth, noise, bus
    ceiling) with thresholds 0.31 / 0.19 and a small mismatch. Measured over seed triples 0-2,
    3-5, 6-8, 9-11 and two threshold settings: errors within 2.3 %.
    """
    dvs = DvsParams(c_on=TRUE_ON, c_off=TRUE_OFF, sigma_threshold=0.01)
    sim = CalibrationSimulation("calibration", [0, 1, 2], 6.0, sensor=SMALL, dvs=dvs)
    return calibrate_from_simulation(
        sim, CalibrationOptions(fit="c", selection=replace(DEFAULT_SELECTION, min_pixels=50))
    )


def test_simulated_thresholds_are_recovered_within_5_percent(sim_result):
    r = sim_result
    assert r.params.c_on == pytest.approx(TRUE_ON, rel=0.05)
    assert r.params.c_off == pytest.approx(TRUE_OFF, rel=0.05)
    # the start (0.26 / 0.24) was off by 16 % and 26 %: the fit moved, and the residual fell
    assert r.rms_after < 0.8 * r.rms_before
    assert len(r.pairs) >= 10 and r.num_residuals > 5_000
    assert all(math.isfinite(p["rms_after"]) for p in r.pairs)
    # the profile carries what was fitted
    assert r.profile.tedi == r.params and r.profile.sensor.shape == SMALL.shape
    assert r.profile.calibration["data"]["simulation"]["seeds"] == [0, 1, 2]


def test_simulated_response_is_recovered_from_the_brackets(sim_result):
    """The calibration scene opens with a static exposure bracket; Debevec-Malik on it gives the
    simulator's response within 0.05 ln units over the valid range."""
    r = sim_result
    assert r.crf_fitted and r.crf_info["frames"] >= 5
    z = np.arange(9, 251)
    assert np.max(np.abs(r.profile.crf.g[z] - default_davis346().g[z])) < 0.05


def test_all_six_parameters_keep_the_thresholds():
    """Fitting the compensation too (knee bounded below) leaves the thresholds within 5 %, and
    the compensation stage (thresholds fixed) never ends worse than it started (no compensation)."""
    dvs = DvsParams(c_on=0.2, c_off=0.28, sigma_threshold=0.01)
    sim = CalibrationSimulation("calibration", [6, 7, 8], 6.0, sensor=SMALL, dvs=dvs)
    r = calibrate_from_simulation(
        sim, CalibrationOptions(fit="all", selection=replace(DEFAULT_SELECTION, min_pixels=50))
    )
    assert r.params.c_on == pytest.approx(0.2, rel=0.05)
    assert r.params.c_off == pytest.approx(0.28, rel=0.05)
    assert r.plain is not None and "two stages" in r.method
    comp = r.stages[-1]
    assert comp["rms_after"] <= comp["rms_before"]
    # the profile's residual is the stage's end if the compensation was kept, its start (a = b = 0) if not
    kept = r.compensation["kept"]
    assert math.isclose(comp["rms_after" if kept else "rms_before"], r.rms_after, rel_tol=1e-9)
    for pol in ("on", "off"):
        a, b = getattr(r.params, f"a_{pol}"), getattr(r.params, f"b_{pol}")
        assert a == 0 or b / a >= 50.0 * (1 - 1e-9)  # the knee bound


@pytest.mark.skipif(not SAMPLE.exists(), reason="real sample ../shared/data/davis346_sample.aedat4 not present")
def test_real_sample_runs_and_reports_residuals(tmp_path, capsys):
    """The DAVIS346 sample has 4 frames and 0.02 events per pixel between them: every pixel is
    used (no change threshold, no continuation rule); the fit runs and reports its residuals."""
    out, rep = tmp_path / "cam.json", tmp_path / "report.json"
    assert (
        cli(
            [
                str(SAMPLE),
                "--out",
                str(out),
                "--json",
                str(rep),
                "--min-change",
                "0",
                "--min-pixels",
                "1",
                "--no-continuation",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "RMS residual" in text and f"wrote {out}" in text
    report = json.loads(rep.read_text())
    fit = report["fit"]
    assert math.isfinite(fit["rms_before"]) and math.isfinite(fit["rms_after"])
    assert fit["rms_after"] <= fit["rms_before"]
    assert report["data"]["frames"] == 4 and len(report["pairs"]) == 3
    for p in report["pairs"]:
        assert math.isfinite(p["rms_before"]) and math.isfinite(p["rms_after"])
    prof = load_profile(out)
    assert (prof.sensor.width, prof.sensor.height) == (346, 260)
    assert prof.calibration["rms_after"] == fit["rms_after"]


@pytest.mark.skipif(not SAMPLE.exists(), reason="real sample ../shared/data/davis346_sample.aedat4 not present")
def test_real_sample_with_the_default_selection_says_what_is_missing(tmp_path):
    with pytest.raises(ParameterError, match="no frame pair qualifies") as e:
        calibrate_from_recordings([SAMPLE])
    assert "\n" not in str(e.value)


def test_profile_round_trips_through_json(tmp_path, sim_result):
    out = tmp_path / "p.json"
    out.write_text(json.dumps(sim_result.profile.to_dict()))
    back = load_profile(out)
    assert back == sim_result.profile  # sensor, response, TEDI parameters, limits
    assert back.calibration == json.loads(json.dumps(sim_result.profile.calibration))
    assert back.to_dict() == json.loads(out.read_text())


def test_out_is_not_overwritten_without_force(tmp_path):
    out = tmp_path / "p.json"
    out.write_text("keep me")
    argv = [
        "--sim",
        "calibration",
        "--sensor",
        "32x24",
        "--duration",
        "1.5",
        "--out",
        str(out),
        "--min-pixels",
        "20",
        "--fit",
        "c",
    ]
    with pytest.raises(ParameterError, match="already exists; pass --force"):
        cli(argv)
    assert out.read_text() == "keep me"
    assert cli(argv + ["--force"]) == 0
    assert load_profile(out).sensor.shape == (24, 32)


@pytest.mark.parametrize(
    "argv, match",
    [
        ([], "nothing to calibrate on"),
        (["x.aedat4", "--sim", "calibration"], "not both"),
        (["missing.aedat4"], "no such file"),
        (["--sim", "tunnel"], "unknown scenario"),
        (["--sim", "calibration", "--seeds", "3..1"], "--seeds"),
        (["--sim", "calibration", "--init", "0.3"], "--init"),
        (["--sim", "calibration", "--init", "0.3,-1"], "contrast threshold c_off"),
        (["--sim", "calibration", "--fit", "c_on,gamma"], "--fit"),
        (["--sim", "calibration", "--sensor", "big"], "--sensor"),
        (["--sim", "calibration", "--max-lag", "0"], "--max-lag = 0 is out of range"),
        (["--sim", "calibration", "--max-lag", "51"], "--max-lag = 51 is out of range"),
        (["--sim", "calibration", "--duration=-1"], "--duration"),
        (["--sim", "calibration", "--min-change", "nan"], "--min-change must be finite"),
    ],
)
def test_bad_input_gives_one_line_errors(tmp_path, monkeypatch, capsys, argv, match):
    from necviz.commands.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", *argv, "--out", "p.json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and match in err and "\n" not in err, err
    assert not (tmp_path / "p.json").exists()


def test_bad_output_paths(tmp_path):
    rec = tmp_path / "rec.aedat4"
    rec.write_bytes(b"x")
    (tmp_path / "d.json").mkdir()
    (tmp_path / "f").write_text("a file where a folder would be")
    for out, match in (
        ("p.txt", "expects a .json"),
        (str(tmp_path / "f" / "p.json"), "Not a directory"),
        (str(tmp_path / "d.json"), "is a folder"),
    ):
        with pytest.raises(ParameterError, match=match):
            cli(["--sim", "calibration", "--out", out])
    with pytest.raises(ParameterError, match="same file"):
        cli(["--sim", "calibration", "--out", str(tmp_path / "a.json"), "--json", str(tmp_path / "a.json")])
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(ProfileError, match="not a necviz camera profile"):
        cli(["--sim", "calibration", "--out", str(tmp_path / "b.json"), "--profile", str(bad)])


def test_seeds_syntax():
    assert parse_seeds("0..4") == [0, 1, 2, 3, 4]
    assert parse_seeds("7") == [7]
    assert parse_seeds("1,5,9") == [1, 5, 9]
    for bad in ("a", "-1", "4..2", ""):
        with pytest.raises(ParameterError):
            parse_seeds(bad)


def test_memory_stays_bounded_and_pairs_spread():
    """With room for 4 pairs the collector keeps at most 4, thinned evenly over the run."""
    from necviz.calibration import simulate_calibration_stream

    scene = CalibrationScene(SensorGeometry(32, 24), duration_us=3_000_000, seed=2)
    col = PairCollector(default_davis346(), replace(DEFAULT_SELECTION, min_pixels=20), CollectorOptions(max_pairs=4))
    col.begin("sim")
    for packet in simulate_calibration_stream(scene, dvs=DvsParams(sigma_threshold=0.01)):
        col.feed(packet)
        assert len(col.pairs) <= 4
        assert col._buffered <= 2_000_000
    col.finish()
    assert col.qualifying > 8 and col.stride >= 2
    kept = [p.seq_cur for p in col.pairs]
    assert kept == sorted(kept) and kept[-1] - kept[0] > 0.4 * col.frames


def test_calibration_scene_is_deterministic_and_goes_both_ways():
    a = CalibrationScene(SMALL, duration_us=3_000_000, seed=4)
    b = CalibrationScene(SMALL, duration_us=3_000_000, seed=4)
    c = CalibrationScene(SMALL, duration_us=3_000_000, seed=5)
    assert np.array_equal(a.log_irradiance(1_234_567), b.log_irradiance(1_234_567))
    assert not np.array_equal(a.log_irradiance(1_234_567), c.log_irradiance(1_234_567))
    deltas = [ch.delta_log for ch in a.changes]
    assert min(deltas) < 0 < max(deltas)
    # static during the bracket opening; the mean follows the documented levels
    assert np.array_equal(a.log_irradiance(0), a.log_irradiance(a.bracket_us - 1))
    for t in (0, 1_500_000, 2_900_000):
        assert float(a.log_irradiance(t).mean()) == pytest.approx(a.mean_log(t), abs=0.02)
    with pytest.raises(ParameterError, match="contrast"):
        CalibrationScene(SMALL, options=CalibrationSceneOptions(contrast=5.0))


def test_default_sim_profile_is_the_shipped_calibration():
    prof = default_sim_profile()
    assert (prof.sensor.width, prof.sensor.height) == (346, 260)
    cal = prof.calibration
    assert cal["data"]["simulation"]["scenarios"] == ["calibration"]  # held out from every evaluation preset
    assert 0.15 < prof.tedi.c_on < 0.4 and 0.15 < prof.tedi.c_off < 0.4
    # the simulator's own thresholds (DvsParams: 0.26 / 0.24), fitted on the pairs below its bus ceiling
    assert prof.tedi.c_on == pytest.approx(0.26, rel=0.02) and prof.tedi.c_off == pytest.approx(0.24, rel=0.02)
    # (the profile's residual over all pairs need not fall: thresholds fitted below the ceiling and, when the
    # held-out pairs reject it, no compensation: tests/test_compensation_holdout.py)
    assert "compensation" in cal and isinstance(cal["compensation"]["kept"], bool)
    assert isinstance(prof, CameraProfile) and isinstance(prof.tedi, TediParams)


def test_threshold_intervals_cover_the_truth_where_the_standard_errors_do_not():
    """The simulated DAVIS346 (c_on 0.26, c_off 0.24), seed 0, 6 s, the command's defaults: the
    Gauss-Newton standard errors (pixels taken as independent) put c_on at 0.254 ± 0.0003, twenty of
    them from the truth; the bootstrap over frame pairs gives an interval that holds it, for both
    thresholds (benchmarks/calibration_coverage.py measures how often over 20 held-out seeds)."""
    from necviz.calibration.bootstrap import FEW_PAIRS

    truth = {"c_on": DvsParams().c_on, "c_off": DvsParams().c_off}
    r = calibrate_from_simulation(CalibrationSimulation("calibration", [0], 6.0), CalibrationOptions())
    b = r.bootstrap
    assert b is not None and b["pairs"] >= 10 and b["level"] == 0.95 and b["undetermined"] < b["replicates"] // 10
    se = r.stderr["c_on"]
    assert abs(r.params.c_on - truth["c_on"]) > 1.96 * se  # what the standard error claimed, and missed
    text = r.summary()
    for name, true in truth.items():
        lo, hi = b["intervals"][name]
        assert lo <= getattr(r.params, name) <= hi
        assert lo <= true <= hi, (name, lo, hi)
        assert hi - lo > 10 * 2 * 1.96 * r.stderr[name]  # not absurdly narrow
        assert f"[{lo:.4f}, {hi:.4f}]" in text
        n_eff = b["effective_pairs"][name]
        assert 1 <= n_eff <= b["pairs"]
        if n_eff >= FEW_PAIRS:
            assert hi - lo < 0.1  # nor uninformative
        else:  # a wide interval says why
            assert f"rests on {n_eff:.1f} pairs' worth of data" in text
    if r.rms_after > r.rms_before:  # the all-pairs residual rose: the summary says why
        assert "it rose: the thresholds are fitted on the" in text
    assert r.profile.calibration["intervals"]["c_off"] == b["intervals"]["c_off"]
