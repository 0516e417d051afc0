"""Simulated APS frames and cameras: frame physics, closed-loop timing, shared events, determinism."""

import math

import numpy as np
import pytest

from necviz.core.errors import ParameterError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.aps import ApsParams, expose, integrate_samples
from necviz.drivers.sim.dvs import DvsParams
from necviz.drivers.sim.rig import RigOptions, SimRig
from necviz.drivers.sim.scene import FunctionScene
from necviz.drivers.source import Source

SENSOR = SensorGeometry(48, 32)


def _field():
    yy, xx = np.mgrid[0:32, 0:48]
    return (5.0 + 0.6 * np.sin(xx / 5.0) * np.cos(yy / 4.0)).astype(np.float32)


def static_scene(duration_us=100_000):
    base = _field()
    return FunctionScene(lambda t, s: base, SENSOR, duration_us)


def step_scene(step_t=50_000, delta=3.0, duration_us=120_000):
    base = _field()
    return FunctionScene(lambda t, s: base + (delta if t > step_t else 0.0), SENSOR, duration_us)


def frames_of(source):
    return [p for _, p in source.packets() if isinstance(p, Frame)]


def test_integrate_samples_is_exact_for_piecewise_linear_light():
    times = np.array([0.0, 10.0, 20.0, 40.0])
    vals = [np.full((2, 2), v, np.float32) for v in (1.0, 3.0, 3.0, 7.0)]
    # ∫ over [5, 30]: [5,10] avg 2.5 (x5) + [10,20] 3 (x10) + [20,30] avg 4 (x10) = 12.5+30+40 = 82.5
    out = integrate_samples(times, vals, 5.0, 30.0)
    assert np.allclose(out, 82.5 / 25.0)
    with pytest.raises(ParameterError, match="not covered"):
        integrate_samples(times, vals, 30.0, 50.0)


def test_frames_measure_the_irradiance_through_the_response(crf):
    """Valid pixels: g(Z) - ln T - ln K equals ln L within shot/read noise and quantisation."""
    base = _field()
    for exposure, gain in ((1_500.0, 1.0), (6_000.0, 1.0), (800.0, 4.0)):
        img = expose(np.exp(base), exposure, gain, crf, ApsParams(), np.random.default_rng(1))
        valid = (img >= 9) & (img <= 250)
        assert valid.mean() > 0.5
        err = crf.g[img[valid]] - math.log(exposure / 1e6) - math.log(gain) - base[valid]
        assert abs(err.mean()) < 0.01
        # expected spread per pixel: shot + read noise in ln units, plus 8-bit quantisation
        electrons = ApsParams().electrons_at_mid * exposure / 1e6 * np.exp(base[valid])
        sigma_noise = np.sqrt(electrons + ApsParams().read_noise_e ** 2) / electrons
        z = img[valid].astype(int)
        sigma_q = (crf.g[np.minimum(z + 1, 255)] - crf.g[np.maximum(z - 1, 0)]) / 2 / math.sqrt(12)
        normalised = err / np.sqrt(sigma_noise**2 + sigma_q**2)
        assert 0.8 < normalised.std() < 1.2  # the noise is there, and of the modelled size
        assert np.max(np.abs(normalised)) < 5.5


def test_over_exposure_happens_exactly_where_physics_says(crf):
    base = _field()
    aps = ApsParams(noise=False)
    for exposure in (2_000.0, 5_000.0, 12_000.0, 30_000.0):
        img = expose(np.exp(base), exposure, 1.0, crf, aps, None)
        log_h = base + math.log(exposure / 1e6)
        expected_over = crf.intensity(log_h) >= 254.5
        assert np.array_equal(img == 255, expected_over)
    assert (expose(np.exp(base), 30_000.0, 1.0, crf, aps, None) == 255).mean() > 0.2


def test_light_changing_during_the_exposure_is_averaged(crf):
    """A +3 step half-way through a 4 ms exposure: the frame sees the mean irradiance, not either level."""
    cam = SimRig(
        step_scene(step_t=3_000),
        {"camera": (4_000, 1.0)},
        aps=ApsParams(noise=False),
        dvs=DvsParams.ideal(),
        options=RigOptions(first_start_us=1_000, sample_us=250),
    )
    f0 = frames_of(cam)[0]
    assert (f0.exposure_start_us, f0.exposure_end_us) == (1_000, 5_000)
    log_h = np.log(np.exp(_field()) * (1 + math.exp(3.0)) / 2) + math.log(4_000 / 1e6)
    expected = np.clip(np.rint(crf.intensity(log_h)), 0, 255)
    assert np.max(np.abs(f0.image.astype(int) - expected)) <= 1


def test_commands_apply_only_after_the_latency():
    """A command issued at time t changes only frames whose exposure starts at or after t + latency."""
    aps = ApsParams(latency_us=1_500, noise=False)
    cam = SimRig(static_scene(), {"camera": (2_000, 1.0)}, aps=aps, dvs=DvsParams.ideal())
    assert isinstance(cam, Source) and cam.cameras == ("camera",)
    issue_at = {20_000: 21_000 - 1_500, 41_000: 41_000 - 1_499}  # exposure start -> issue time
    seen = []
    for _, p in cam.packets():
        if isinstance(p, Frame):
            seen.append(p)
        if isinstance(p, ExposureMarker) and p.kind == "end" and p.t_us == 3_000:
            cam.set_exposure("camera", 500, 1.0, issue_time_us=issue_at[20_000])  # in time for the 21 ms frame
            cam.set_exposure("camera", 700, 2.0, issue_time_us=issue_at[41_000])  # 1 µs late for the 41 ms frame
    starts = [f.exposure_start_us for f in seen]
    assert starts[:4] == [1_000, 21_000, 41_000, 61_000]
    assert [f.exposure_us for f in seen[:4]] == [2_000, 500, 500, 700]
    assert [f.gain for f in seen[:4]] == [1.0, 1.0, 1.0, 2.0]
    recs = cam.commands("camera")
    assert [r.applied_start_us for r in recs] == [21_000, 61_000]


def test_commands_are_clamped_to_the_camera_limits():
    aps = ApsParams(exposure_min_us=10, exposure_max_us=15_000, gain_max=4.0, noise=False)
    cam = SimRig(static_scene(60_000), {"camera": (2_000, 1.0)}, aps=aps, dvs=DvsParams.ideal())
    cam.set_exposure("camera", 1e9, 100.0, issue_time_us=0)
    f = frames_of(cam)
    assert f[1].exposure_us == 15_000 and f[1].gain == 4.0
    with pytest.raises(ParameterError, match="exposure_us"):
        cam.set_exposure("camera", float("nan"))
    with pytest.raises(ParameterError, match="gain"):
        cam.set_exposure("camera", 100, 0.5)


def test_cameras_share_one_event_stream_but_not_their_exposures():
    scene = step_scene()
    rig = SimRig(scene, {"a": (2_000, 1.0), "b": (300, 1.0)}, dvs=DvsParams.ideal(), aps=ApsParams(noise=False))
    shared, frames = [], {"a": [], "b": []}
    for name, p in rig.packets():
        if name is None:
            assert isinstance(p, EventBatch)
            shared.append(p.events)
        elif isinstance(p, Frame):
            frames[name].append(p)
    ev = np.concatenate(shared)
    assert ev.size > 0 and np.all(np.diff(ev["t"]) >= 0)
    solo = SimRig(step_scene(), ["a"], dvs=DvsParams.ideal(), aps=ApsParams(noise=False))
    ev_solo = np.concatenate([p.events for n, p in solo.packets() if n is None])
    assert np.array_equal(ev, ev_solo)  # events do not depend on cameras or exposures
    assert {f.exposure_us for f in frames["a"]} == {2_000} and {f.exposure_us for f in frames["b"]} == {300}
    over_a = [float((f.image == 255).mean()) for f in frames["a"]]
    over_b = [float((f.image == 255).mean()) for f in frames["b"]]
    assert over_a[-1] > 0.7 and over_b[-1] < 0.05  # after +3 ln the long exposure saturates


def test_stream_order_per_camera_is_what_the_estimator_needs():
    """Markers and frames interleave with the shared events in time order for every camera."""
    from necviz.core.event_model import TediParams
    from necviz.core.ptedi import PeripheralEstimator

    rig = SimRig(
        step_scene(), {"a": (2_000, 1.0), "b": (5_000, 1.0)}, dvs=DvsParams.ideal(), aps=ApsParams(noise=False)
    )
    est = {n: PeripheralEstimator(SENSOR, TediParams(0.26, 0.24)) for n in ("a", "b")}
    last_t = -1
    for name, p in rig.packets():
        t = int(p.events["t"][0]) if name is None else (p.t_us if isinstance(p, ExposureMarker) else p.exposure_end_us)
        assert t >= last_t or isinstance(p, Frame)
        last_t = max(last_t, t if not isinstance(p, Frame) else last_t)
        for n in [name] if name else list(est):
            est[n].feed(p)
    assert all(e.frames_seen >= 5 for e in est.values())


def test_same_seed_same_output_different_seed_different_noise():
    def run(seed):
        cam = SimRig(static_scene(50_000), {"camera": (2_000, 1.0)}, seed=seed)
        return [
            (p.events.copy() if isinstance(p, EventBatch) else p.image.copy())
            for _, p in cam.packets()
            if isinstance(p, (EventBatch, Frame))
        ]

    a, b, c = run(1), run(1), run(2)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    fa = [x for x in a if x.dtype == np.uint8]
    fc = [x for x in c if x.dtype == np.uint8]
    assert any(not np.array_equal(x, y) for x, y in zip(fa, fc, strict=True))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(frame_interval_us=10_000, exposure_max_us=10_000), "fit in the frame interval"),
        (dict(electrons_at_mid=float("nan")), "electrons_at_mid"),
        (dict(exposure_min_us=0), "positive"),
        (dict(gain_max=0.5), "gain_max"),
    ],
)
def test_bad_aps_parameters(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        ApsParams(**kwargs)


def test_bad_rig_parameters():
    with pytest.raises(ParameterError, match="at least one camera"):
        SimRig(static_scene(), [])
    with pytest.raises(ParameterError, match="sample_us"):
        SimRig(static_scene(), ["a"], options=RigOptions(sample_us=0))
    with pytest.raises(ParameterError, match="Scene"):
        SimRig("tunnel", ["a"])
    rig = SimRig(static_scene(), ["a"])
    with pytest.raises(ParameterError, match="no simulated camera named 'b'"):
        rig.set_exposure("b", 100)


def test_a_long_closed_loop_keeps_the_command_list_bounded(monkeypatch):
    """Commands issued on every batch for a long run: the rig keeps a bounded history, and the newest
    old-enough command still applies at each exposure start."""
    import necviz.drivers.sim.rig as cam_mod

    monkeypatch.setattr(cam_mod, "COMMAND_HISTORY", 10)
    rig = SimRig(static_scene(400_000), {"camera": (2_000, 1.0)}, dvs=DvsParams.ideal(), aps=ApsParams(noise=False))
    rig.cams["camera"].history = cam_mod.deque(maxlen=10)
    frames, issued = [], 0
    for _, p in rig.packets():
        if isinstance(p, ExposureMarker):
            rig.set_exposure("camera", 1_000 + (issued % 7) * 100, 1.0)  # a new setting at every marker
            issued += 1
        elif isinstance(p, Frame):
            frames.append(p)
    cmds = rig.commands("camera")
    assert issued >= 38 and len(cmds) <= 10 + 2
    applied = [c for c in cmds if c.applied_start_us is not None]
    by_start = {f.exposure_start_us: f for f in frames}
    assert applied and all(
        by_start[c.applied_start_us].exposure_us == round(c.exposure_us)
        for c in applied
        if c.applied_start_us in by_start
    )
