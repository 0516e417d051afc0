"""Scenario presets of the simulator (drivers/sim/scenes/)."""

import re
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import pytest

from necviz.core.errors import ParameterError, ProfileError
from necviz.core.sensor import DAVIS240, DAVIS346
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.rig import RigOptions
from necviz.drivers.sim.scene import FunctionScene, LightingChange, Scene, db_to_log
from necviz.drivers.sim.scenes import (
    COMMON_PARAMS,
    SCENARIOS,
    make_scenario,
    scenario_from_toml,
    scenario_params,
    scenario_params_markdown,
)
from necviz.drivers.sim.scenes.static_lab import FIRST_START_US, FRAME_INTERVAL_US

NAMES = sorted(SCENARIOS)


@pytest.fixture(scope="module")
def scenes():
    return {n: make_scenario(n, seed=0) for n in NAMES}


@pytest.fixture(scope="module")
def tunnel(scenes):
    return scenes["tunnel_exit"]


def to8(img, centre=None):
    """8-bit view of ln L around ``centre`` (default: median), spanning the camera's ~3.3 ln range."""
    c = float(np.median(img)) if centre is None else centre
    return np.clip((img - c) / 3.3 * 255 + 128, 0, 255).astype(np.uint8)


def orb_matches(a8, b8):
    orb = cv2.ORB_create(nfeatures=1000)
    ka, da = orb.detectAndCompute(a8, None)
    kb, db = orb.detectAndCompute(b8, None)
    if da is None or db is None:
        return ka, kb, []
    m = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    m = [x for x in m if x.distance < 40]
    return ka, kb, m


# -- every preset ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_preset_basic_and_deterministic(name, scenes):
    s = scenes[name]
    assert isinstance(s, Scene) and s.name == name
    d = s.duration_us
    times = [0, 0.37 * d, 0.41 * d, d]
    again = make_scenario(name, seed=0)
    other = make_scenario(name, seed=1)
    for t in times:
        a = s.log_irradiance(t)
        assert a.dtype == np.float32 and a.shape == DAVIS346.shape
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a, again.log_irradiance(t))
    diff = np.abs(s.log_irradiance(times[1]) - other.log_irradiance(times[1]))
    assert diff.mean() > 0.05, "a different seed must give a different texture"
    # the scene has structure a feature matcher can use, not just noise
    k, _, m = orb_matches(to8(s.log_irradiance(times[1])), to8(s.log_irradiance(times[1] + 2000)))
    assert len(k) > 150 and len(m) > 60, (len(k), len(m))


@pytest.mark.parametrize("name", NAMES)
def test_duration_sensor_and_changes_inside(name):
    s = make_scenario(name, sensor=DAVIS240, duration_us=1_200_000, seed=2)
    assert s.duration_us == 1_200_000
    assert s.log_irradiance(s.duration_us).shape == DAVIS240.shape
    assert all(0 <= c.t_us <= s.duration_us for c in s.changes)
    assert all(isinstance(c, LightingChange) for c in s.changes)
    assert set(s.params) == set(scenario_params(name))


# -- tunnel_exit ---------------------------------------------------------------------------------
@pytest.mark.parametrize("step_db", [60.0, 100.0])
def test_tunnel_step_over_transition(step_db):
    s = make_scenario("tunnel_exit", seed=1, step_db=step_db, transition_ms=40, change_jitter_ms=0)
    step = db_to_log(step_db)
    t_exit = 0.4 * s.duration_us
    assert s.changes[0].t_us == int(t_exit)
    before, after = s.log_irradiance(t_exit - 21_000), s.log_irradiance(t_exit + 21_000)
    # typical pixel (median, unaffected by the small portal): the full step
    assert abs((np.median(after) - np.median(before)) - step) < 0.25
    # mean change equals the documented delta and is the step minus the portal's share
    assert abs((after.mean() - before.mean()) - s.changes[0].delta_log) < 0.1
    assert step * 0.8 < s.changes[0].delta_log < step
    # the step happens within the transition: little change well before/after it, half at the exit
    m = lambda t: float(s.log_irradiance(t).mean())
    assert abs(m(t_exit - 40_000) - m(t_exit - 21_000)) < 0.1 * step
    assert abs(m(t_exit + 60_000) - m(t_exit + 21_000)) < 0.05 * step
    mid = (m(t_exit) - before.mean()) / (after.mean() - before.mean())
    assert 0.3 < mid < 0.7
    # the tunnel surfaces (outside the portal) average inside_log at t = 0
    img0 = s.log_irradiance(0)
    assert abs(img0[img0 < 5.0 + step / 2].mean() - 5.0) < 0.1


def test_tunnel_portal_grows_before_exit(tunnel):
    t_exit = 0.4 * tunnel.duration_us
    thr = 5.0 + db_to_log(60) / 2
    frac = [float((tunnel.log_irradiance(t) > thr).mean()) for t in (0.0, t_exit - 400_000, t_exit - 25_000)]
    assert 0.0 < frac[0] < frac[1] < frac[2] <= 0.12


def test_tunnel_expanding_flow(tunnel):
    t0 = 0.2 * tunnel.duration_us
    a, b = tunnel.log_irradiance(t0), tunnel.log_irradiance(t0 + 8000)
    ka, kb, m = orb_matches(to8(a), to8(b))
    fx, fy = tunnel.annotations["foe"]
    out = []
    for x in m:
        pa, pb = np.array(ka[x.queryIdx].pt), np.array(kb[x.trainIdx].pt)
        d, r = pb - pa, pa - (fx, fy)
        if np.linalg.norm(d) > 0.5 and np.linalg.norm(r) > 20:
            out.append(np.dot(d, r) / np.linalg.norm(d) / np.linalg.norm(r))
    assert len(out) > 30
    assert np.mean(np.array(out) > 0.7) > 0.8, "features must move away from the focus of expansion"


def test_tunnel_pedestrian_after_exit():
    s = make_scenario("tunnel_exit", seed=0, pedestrian_delay_ms=100, change_jitter_ms=0)
    t_ped = s.annotations["pedestrian_enters_us"]
    assert t_ped == pytest.approx(0.4 * s.duration_us + 100_000)
    with_p = s.log_irradiance(t_ped + 500_000)
    ref = make_scenario("tunnel_exit", seed=0, pedestrian_delay_ms=1e5, change_jitter_ms=0)  # never enters
    diff = np.abs(with_p - ref.log_irradiance(t_ped + 500_000)) > 0.05
    ys, xs = np.nonzero(diff)
    assert 0.2 * 48 * 19 < diff.sum() < 3 * 48 * 19
    assert xs.min() > 346 / 2  # right of the road centre, walking in from the right
    np.testing.assert_array_equal(s.log_irradiance(t_ped - 50_000), ref.log_irradiance(t_ped - 50_000))


def test_tunnel_max_log_rate_bounds_transition():
    s = make_scenario("tunnel_exit", seed=0, speed_kmh=0.0, portal_frac=0.0)
    t0 = 0.4 * s.duration_us - 20_000
    imgs = [s.log_irradiance(t0 + k * 1000) for k in range(41)]
    observed = max(np.abs(b - a).max() / 1000 for a, b in pairwise(imgs))
    assert observed > 0
    assert s.max_log_rate(t0, t0 + 40_000) >= observed
    assert s.max_log_rate(0, 1000) < observed / 100


# -- indoor_outdoor ------------------------------------------------------------------------------
def test_indoor_outdoor_step_and_shake():
    s = make_scenario("indoor_outdoor", seed=0, change_jitter_ms=0)
    t_exit, tr = 0.5 * s.duration_us, 300_000
    before, after = s.log_irradiance(t_exit - tr / 2 - 1000), s.log_irradiance(t_exit + tr / 2 + 1000)
    assert abs((np.median(after) - np.median(before)) - db_to_log(70)) < 0.4
    assert s.changes[0].t_us == int(t_exit)
    # hand shake: the view moves even far from the door, but only a few pixels
    a, b = s.log_irradiance(100_000), s.log_irradiance(150_000)
    assert np.abs(a - b).mean() > 0.02
    with pytest.raises(ParameterError, match="step_db"):
        make_scenario("indoor_outdoor", step_db=90)


# -- flicker -------------------------------------------------------------------------------------
@pytest.mark.parametrize("hz", [100.0, 120.0])
def test_flicker_spectrum_peaks_at_mains(hz):
    s = make_scenario("flicker", seed=4, mains_hz=hz)
    fs = 4000.0
    ts = np.arange(0, 0.25, 1 / fs) * 1e6  # before the first switch (30 % of 1 s)
    mask = s.lamp_mask
    assert 0.02 < mask.mean() < 0.5
    sig = np.array([s.log_irradiance(t)[mask].mean() for t in ts])
    spec = np.abs(np.fft.rfft(sig - sig.mean()))
    freqs = np.fft.rfftfreq(len(sig), 1 / fs)
    assert freqs[np.argmax(spec)] == pytest.approx(hz, abs=4.0)
    # the unlit part does not flicker
    far = np.array([s.log_irradiance(t)[~mask].mean() for t in ts[:40]])
    assert np.ptp(far) < np.ptp(sig) / 5
    assert s.max_log_rate(0, 1000) >= np.abs(np.diff(sig)).max() * fs / 1e6


def test_flicker_switch_times():
    s = make_scenario(
        "flicker", seed=0, duration_us=2_000_000, switch_times_s=[0.5, 1.5], depth=0.0, change_jitter_ms=0
    )
    assert [c.t_us for c in s.changes] == [500_000, 1_500_000]
    assert [c.label for c in s.changes] == ["light on", "light off"]
    m = lambda t: float(s.log_irradiance(t).mean())
    assert m(0.6e6) - m(0.4e6) == pytest.approx(s.changes[0].delta_log, abs=1e-3)
    assert m(1.6e6) - m(1.4e6) == pytest.approx(s.changes[1].delta_log, abs=1e-3)
    assert s.changes[0].delta_log > 0.5 * db_to_log(20)
    with pytest.raises(ParameterError, match="increasing"):
        make_scenario("flicker", switch_times_s=[0.5, 0.2])


# -- static_lab ----------------------------------------------------------------------------------
def test_static_lab_levels_and_no_motion():
    steps = [(0.5, 20.0), (1.0, -30.0), (1.5, 0.0)]
    s = make_scenario("static_lab", duration_us=2_000_000, seed=0, steps=steps, ramp_ms=1.0, change_jitter_ms=0)
    assert [c.t_us for c in s.changes] == [500_000, 1_000_000, 1_500_000]
    assert [round(c.delta_log, 6) for c in s.changes] == [round(db_to_log(x), 6) for x in (20, -50, 30)]
    base = s.log_irradiance(0.2e6)
    assert float(base.mean()) == pytest.approx(5.0, abs=1e-4)
    for t, lv in [(0.3e6, 0), (0.7e6, 20), (1.2e6, -30), (1.9e6, 0)]:
        img = s.log_irradiance(t)
        assert float(img.mean()) - 5.0 == pytest.approx(db_to_log(lv), abs=1e-3)
        np.testing.assert_array_equal(img, s.log_irradiance(t + 1000))  # static between steps
        np.testing.assert_allclose(img - base, db_to_log(lv), atol=1e-4)  # a uniform light change
    assert s.max_log_rate(0.5e6, 0.5e6 + 500) > 0 and s.max_log_rate(0.6e6, 0.7e6) == 0
    with pytest.raises(ParameterError, match="steps"):
        make_scenario("static_lab", steps=[(0.5, 20.0, 3)])
    with pytest.raises(ParameterError, match="out of range"):
        make_scenario("static_lab", duration_us=1_000_000, steps=[(2.0, 20.0)])


def default_frame_clock():
    """(first exposure start, frame interval, command latency) of SimRig/ApsParams defaults, in µs."""
    return (
        RigOptions().first_start_us,
        ApsParams().frame_interval_us,
        ApsParams().latency_us,
    )


def meets_frame_clock(t0_us, t1_us, duration_us) -> bool:
    """Whether [t0, t1] (a change and its ramp) meets [start - latency, start + 1 ms] of an exposure start."""
    first, period, latency = default_frame_clock()
    starts = np.arange(first, duration_us + period, period)
    return bool(np.any((t0_us <= starts + 1000) & (t1_us >= starts - latency)))


OLD_STEPS = [(1.0, 20.0), (2.0, -20.0), (3.0, 40.0), (4.0, 0.0)]  # the round times used before


def test_frame_clock_constants_match_the_simulator():
    first, period, _ = default_frame_clock()
    assert (FIRST_START_US, FRAME_INTERVAL_US) == (first, period)


@pytest.mark.parametrize("duration_us", [None, 1_200_000, 300_000])
@pytest.mark.parametrize("seed", [0, 1])
def test_static_lab_default_steps_avoid_the_frame_clock(duration_us, seed):
    s = make_scenario("static_lab", duration_us=duration_us, seed=seed, change_jitter_ms=0)  # the nominal placement
    first, period, _ = default_frame_clock()
    d = s.duration_us
    assert [c.delta_log for c in s.changes] == [db_to_log(x) for x in (20, -40, 60, -40)]
    for c, frac in zip(s.changes, (0.2, 0.4, 0.6, 0.8), strict=True):
        assert not meets_frame_clock(c.t_us, c.t_us + s.ramp_us, d), c
        assert (c.t_us - first) % period == period // 2  # half-way between two exposure starts
        assert 0 <= c.t_us - frac * d < period  # the first such point at or after the nominal fraction
        # the level really changes there (not only the documented time)
        before = float(s.log_irradiance(c.t_us - 1).mean())
        after = float(s.log_irradiance(c.t_us + s.ramp_us + 1).mean())
        assert after - before == pytest.approx(c.delta_log, abs=1e-4)


def test_static_lab_round_times_met_the_clock_and_only_timing_changed():
    old = make_scenario("static_lab", seed=0, steps=OLD_STEPS, change_jitter_ms=0)
    assert all(meets_frame_clock(c.t_us, c.t_us + old.ramp_us, old.duration_us) for c in old.changes)
    new = make_scenario("static_lab", seed=0, change_jitter_ms=0)
    assert [c.t_us for c in new.changes] == [1_011_000, 2_011_000, 3_011_000, 4_011_000]
    for t in (0.5e6, 1.5e6, 2.5e6, 3.5e6, 4.5e6):  # same texture and levels away from the steps
        np.testing.assert_array_equal(new.log_irradiance(t), old.log_irradiance(t))


def test_static_lab_jitter_moves_changes_within_the_bound():
    nominal = [c.t_us for c in make_scenario("static_lab", seed=0, change_jitter_ms=0).changes]
    bound = 10_000
    times = {}
    for seed in range(6):
        s = make_scenario("static_lab", seed=seed, change_jitter_ms=10)
        times[seed] = [c.t_us for c in s.changes]
        assert times[seed] == [c.t_us for c in make_scenario("static_lab", seed=seed, change_jitter_ms=10).changes]
        assert s.params["steps"] == make_scenario("static_lab", seed=seed).params["steps"]  # nominal kept
    off = np.array([np.subtract(t, nominal) for t in times.values()])
    assert np.abs(off).max() <= bound
    assert len({tuple(t) for t in times.values()}) == len(times), "seeds must give different times"
    assert off.min() < -bound / 2 and off.max() > bound / 2 and len(set(off.ravel())) == off.size
    # the light follows the moved times; the texture is the unjittered one
    s, ref = (
        make_scenario("static_lab", seed=2, change_jitter_ms=10),
        make_scenario("static_lab", seed=2, change_jitter_ms=0),
    )
    np.testing.assert_array_equal(s.log_irradiance(0.5e6), ref.log_irradiance(0.5e6))
    for c in s.changes:
        step = float(s.log_irradiance(c.t_us + s.ramp_us + 1).mean() - s.log_irradiance(c.t_us - 1).mean())
        assert step == pytest.approx(c.delta_log, abs=1e-4)
    # zero jitter is the nominal scene
    zero = make_scenario("static_lab", seed=2, change_jitter_ms=0)
    assert zero.changes == ref.changes


@pytest.mark.parametrize("name", ["tunnel_exit", "indoor_outdoor", "flicker"])
def test_change_jitter_other_presets(name):
    ref = make_scenario(name, sensor=DAVIS240, seed=3, change_jitter_ms=0)
    jit = make_scenario(name, sensor=DAVIS240, seed=3, change_jitter_ms=5)
    shift = [a.t_us - b.t_us for a, b in zip(jit.changes, ref.changes, strict=True)]
    assert len(shift) == len(ref.changes) >= 1
    assert all(abs(x) <= 5000 for x in shift) and any(x != 0 for x in shift)
    assert jit.params == {**ref.params, "change_jitter_ms": 5.0}
    default = make_scenario(name, sensor=DAVIS240, seed=3)  # half a frame interval either way
    assert default.changes == make_scenario(name, sensor=DAVIS240, seed=3, change_jitter_ms=10).changes
    assert all(abs(a.t_us - b.t_us) <= 10_000 for a, b in zip(default.changes, ref.changes, strict=True))


def test_change_jitter_handheld_scan_and_errors():
    ref = make_scenario("handheld_scan", sensor=DAVIS240, seed=0, duration_us=1_500_000)
    jit = make_scenario("handheld_scan", sensor=DAVIS240, seed=0, duration_us=1_500_000, change_jitter_ms=100)
    np.testing.assert_array_equal(jit.tex, ref.tex)  # same facade, later shadows
    assert [c.t_us for c in jit.changes] != [c.t_us for c in ref.changes]
    with pytest.raises(ParameterError, match="change_jitter_ms = 10 could reorder switch_times_s"):
        make_scenario("flicker", switch_times_s=[0.5, 0.51], change_jitter_ms=10)
    with pytest.raises(ParameterError, match="change_jitter_ms = -1 is out of range"):
        make_scenario("static_lab", change_jitter_ms=-1)


# -- generated parameter tables ------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_parameter_table_in_docstring(name, scenes):
    cls = SCENARIOS[name]
    assert cls.PARAMS["change_jitter_ms"] is COMMON_PARAMS["change_jitter_ms"]
    table = cls.__doc__[cls.__doc__.index("Parameters (generated from ``PARAMS``") :].splitlines()
    rules = [line for line in table if line.startswith("===")]
    assert len(rules) == 3
    for key, p in cls.PARAMS.items():
        row = next(line for line in table if line.startswith(f"``{key}`` "))
        assert p.default_cell() in row and p.range_cell() in row and row.endswith(p.doc)
        if p.kind == "float":  # the table shows the value the preset really uses
            assert float(p.default_cell()) == scenes[name].params[key]


def test_docs_scenario_section_is_generated():
    text = (Path(__file__).resolve().parents[1] / "docs" / "simulator.md").read_text(encoding="utf-8")
    head = "## Preset parameters\n\n"
    assert text.count(head) == 1
    start = text.index(head) + len(head)
    nxt = re.search(r"^#{1,2} ", text[start:], re.M)
    end = start + nxt.start() if nxt else len(text)
    assert text[start:end] == scenario_params_markdown() + "\n", (
        "docs/simulator.md section out of date: paste necviz.drivers.sim.scenes.scenario_params_markdown()"
    )


# -- handheld_scan -------------------------------------------------------------------------------
def test_handheld_scan_shadow_edges(scenes):
    s = scenes["handheld_scan"]
    assert len(s.changes) >= 1
    H, W = s.sensor.shape
    step = db_to_log(50)
    for c in s.changes:
        centre = lambda t: float(s.log_irradiance(t)[H // 2 - 2 : H // 2 + 3, W // 2 - 2 : W // 2 + 3].mean())
        d = centre(c.t_us + 40_000) - centre(c.t_us - 40_000)
        assert np.sign(d) == np.sign(c.delta_log) and abs(d) > 0.5 * step
    img = s.log_irradiance(s.changes[0].t_us)
    assert np.ptp(img) > 0.9 * step  # sun and shadow both in view
    assert s.max_log_rate(0, 1000) > 0


# -- registry, FunctionScene, TOML ---------------------------------------------------------------
def test_registry_errors():
    with pytest.raises(ParameterError, match="unknown scenario 'tunnel'.*static_lab.*tunnel_exit"):
        make_scenario("tunnel")
    with pytest.raises(ParameterError, match="unknown parameter.*stepdb.*accepted: .*step_db"):
        make_scenario("tunnel_exit", stepdb=60)
    with pytest.raises(ParameterError, match="step_db = 30 is out of range"):
        make_scenario("tunnel_exit", step_db=30)
    with pytest.raises(ParameterError, match="step_db"):
        make_scenario("tunnel_exit", step_db=150)
    with pytest.raises(ParameterError, match="must be a number"):
        make_scenario("tunnel_exit", step_db="90")
    with pytest.raises(ParameterError, match="finite"):
        make_scenario("flicker", depth=float("nan"))
    with pytest.raises(ParameterError, match="exit_s"):
        make_scenario("tunnel_exit", duration_us=1_000_000, exit_s=1.5)
    with pytest.raises(ParameterError, match="seed"):
        make_scenario("static_lab", seed=-1)


def test_function_scene():
    def fn(t_us, sensor):
        yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width]
        return 5.0 + 0.3 * np.sin(xx / 7.0) + (3.0 if t_us > 1e6 else 0.0)

    s = FunctionScene(fn, duration_us=2_000_000, changes=[LightingChange(1_000_000, "step", 3.0)])
    a, b = s.log_irradiance(0), s.log_irradiance(1.5e6)
    assert a.dtype == np.float32 and a.shape == DAVIS346.shape
    assert float((b - a).mean()) == pytest.approx(3.0)
    bad = FunctionScene(lambda t, sensor: np.zeros((10, 10)))
    with pytest.raises(ParameterError, match="shape"):
        bad.log_irradiance(0)


def test_toml_text_and_file(tmp_path):
    text = 'name = "tunnel_exit"\nseed = 3\nduration_s = 2.0\n[params]\nstep_db = 90\n'
    s = scenario_from_toml(text)
    assert (s.name, s.seed, s.duration_us, s.params["step_db"]) == ("tunnel_exit", 3, 2_000_000, 90.0)
    ref = make_scenario("tunnel_exit", seed=3, duration_us=2_000_000, step_db=90)
    np.testing.assert_array_equal(s.log_irradiance(5e5), ref.log_irradiance(5e5))
    p = tmp_path / "lab.toml"
    p.write_text(
        'name = "static_lab"\nduration_us = 1000000\nsensor = "DAVIS240"\n'
        "[params]\nsteps = [[0.25, 10.0], [0.75, -10.0]]\nchange_jitter_ms = 0\n"
    )
    for src in (p, str(p)):
        s = scenario_from_toml(src)
        assert s.sensor == DAVIS240 and [c.t_us for c in s.changes] == [250_000, 750_000]


@pytest.mark.parametrize(
    "text,err,msg",
    [
        ('name = "tunnel_exit"\nseed = \n', ProfileError, "invalid TOML"),
        ("seed = 1\n", ProfileError, 'missing key "name"'),
        ('name = "tunnel_exit"\ncolour = 1\n', ProfileError, "unknown key.*colour"),
        ('name = "tunnel_exit"\nduration_s = -1\n', ProfileError, "duration_s"),
        ('name = "tunnel_exit"\nduration_us = 1.5\n', ProfileError, "duration_us.*whole number"),
        ('name = "tunnel_exit"\nseed = -1\n', ProfileError, "seed"),
        ('name = "tunnel_exit"\nduration_s = 1\nduration_us = 5\n', ProfileError, "not both"),
        ('name = "tunnel_exit"\nsensor = "DAVIS999"\n', ProfileError, "unknown sensor"),
        ('name = "nope"\n', ParameterError, "unknown scenario 'nope'"),
        ('name = "tunnel_exit"\n[params]\nstep_db = 20\n', ParameterError, "step_db = 20 is out of range"),
        ('name = "tunnel_exit"\n[params]\nspeed = 20\n', ParameterError, "unknown parameter.*speed.*speed_kmh"),
    ],
)
def test_toml_errors(text, err, msg):
    with pytest.raises(err, match=msg):
        scenario_from_toml(text)


def test_toml_missing_file(tmp_path):
    with pytest.raises(ProfileError, match="cannot read"):
        scenario_from_toml(tmp_path / "missing.toml")
