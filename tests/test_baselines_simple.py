"""The image-only baselines: Navid (Nourani-Vatani & Roberts 2007), libcaer's built-in AE, fixed."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from necviz.core.control.builtin import BuiltinController
from necviz.core.control.controller import CameraLimits, ExposureCommand
from necviz.core.control.fixed import FixedController
from necviz.core.control.navid import NavidController, NavidOptions, mean_sample_value
from necviz.core.crf import default_davis346
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame

CRF = default_davis346()
_rng = np.random.default_rng(7)
_yy, _xx = np.mgrid[0:48, 0:64]
#: a fixed HDR scene: ln L = 5 + texture in [-1, 1]
SCENE = 5.0 + np.clip(0.5 * np.sin(_xx / 5.0) + 0.5 * np.cos(_yy / 7.0) + 0.3 * _rng.standard_normal(_yy.shape), -1, 1)


def render(log_l: np.ndarray, exposure_us: int, gain: float) -> np.ndarray:
    h = log_l + math.log(exposure_us / 1e6) + math.log(gain)
    return np.clip(np.round(CRF.intensity(h)), 0, 255).astype(np.uint8)


def closed_loop(ctrl, log_l, n_frames, log_l_after=None, switch_at=None):
    """Simulated camera: each command applies to the next frame. Returns [(T, K, MSV, cmd)]."""
    cmd = ctrl.initial_command(0)
    t, out = 0, []
    for i in range(n_frames):
        scene = log_l_after if (switch_at is not None and i >= switch_at) else log_l
        T, K = max(1, int(round(cmd.exposure_us))), cmd.gain
        img = render(scene, T, K)
        new = ctrl.on_frame(Frame(img, t, t + T, K, i))
        out.append((T, K, mean_sample_value(img), new))
        if new is not None:
            check_command(new, ctrl.limits)
            cmd = new
        t += T + 1_000
    return out


def check_command(cmd, limits):
    assert isinstance(cmd, ExposureCommand)
    assert math.isfinite(cmd.exposure_us) and math.isfinite(cmd.gain)
    assert limits.exposure_min_us <= cmd.exposure_us <= limits.exposure_max_us
    assert 1.0 <= cmd.gain <= limits.gain_max


def frames_to_settle(trace, tol=0.3):
    """First frame index from which the MSV stays within tol of 2.5."""
    msv = [m for _, _, m, _ in trace]
    for i in range(len(msv)):
        if all(abs(m - 2.5) <= tol for m in msv[i:]):
            return i
    return None


# ---------------------------------------------------------------------------------------- Navid
def test_msv_definition():
    # one pixel per region -> (1+2+3+4+5)/5 = 3; all in the lowest region -> 1; all top -> 5
    assert mean_sample_value(np.array([[0, 60, 120, 170, 230]], np.uint8)) == pytest.approx(3.0)
    assert mean_sample_value(np.zeros((3, 3), np.uint8)) == 1.0
    assert mean_sample_value(np.full((3, 3), 255, np.uint8)) == 5.0
    # region boundaries: 5 equal regions of 0..255
    assert mean_sample_value(np.array([[51, 52]], np.uint8)) == pytest.approx(1.5)
    assert mean_sample_value(np.array([[204, 205]], np.uint8)) == pytest.approx(4.5)
    assert mean_sample_value(np.array([[102, 103, 153, 154]], np.uint8)) == pytest.approx(3.0)
    # weights: only the bright half counts
    img = np.array([[0, 255]], np.uint8)
    assert mean_sample_value(img, np.array([[0, 1]])) == 5.0


@pytest.mark.parametrize("start_us", [50, 500_000])  # ~6.6 EV too dark, ~6.9 EV too bright
def test_navid_settles_static_scene(start_us):
    limits = CameraLimits(10.0, 1_000_000.0, 1.0)
    trace = closed_loop(NavidController(limits, start_us), SCENE, 16)
    first = trace[0][2]
    assert (first < 1.3) if start_us == 50 else (first > 4.7)  # really starts far off
    settled = frames_to_settle(trace)
    assert settled is not None and settled <= 10, [round(m, 2) for _, _, m, _ in trace]
    assert abs(trace[-1][2] - 2.5) <= 0.3
    last_t = [T for T, _, _, _ in trace[-5:]]
    assert max(last_t) / min(last_t) < 1.05  # stable: little change over the last frames
    assert all(K == 1.0 for _, K, _, _ in trace)


def test_navid_exposure_first_then_gain_and_back():
    limits = CameraLimits(10.0, 20_000.0, 8.0)
    dark = SCENE - 2.0  # needs ~40 ms at gain 1 -> too dark for T_max = 20 ms
    ctrl = NavidController(limits, 1_000.0)
    trace = closed_loop(ctrl, dark, 40, log_l_after=SCENE + 1.0, switch_at=20)
    t_max = limits.exposure_max_us
    first_gain = next(i for i, (_, K, _, _) in enumerate(trace) if K > 1.0)
    assert trace[first_gain - 1][0] >= t_max - 1  # exposure reached T_max first
    for T, K, _, cmd in trace:
        if K > 1.0:
            assert T >= t_max - 1  # a frame with gain was always taken at T_max
        if cmd is not None and cmd.gain > 1.0:
            assert T >= t_max - 1 and cmd.exposure_us == t_max  # gain only rises from T_max
    assert abs(trace[19][2] - 2.5) <= 0.3 and trace[19][1] > 1.0  # settled with gain in the dark
    # scene brightens: gain hands back to 1, then the exposure loop shortens the exposure
    T_end, K_end, msv_end, _ = trace[-1]
    assert K_end == 1.0 and T_end < t_max / 2 and abs(msv_end - 2.5) <= 0.3


def test_navid_foreign_gain_below_t_max_is_resplit():
    limits = CameraLimits(10.0, 20_000.0, 8.0)
    ctrl = NavidController(limits, 5_000.0, 4.0)
    cmd = ctrl.on_frame(Frame(np.full((4, 4), 250, np.uint8), 0, 5_000, 4.0))  # too bright
    assert cmd.gain == 1.0 and cmd.exposure_us < 5_000 * 4.0  # darker product, gain dropped first
    ctrl = NavidController(limits, 5_000.0, 4.0)
    cmd = ctrl.on_frame(Frame(np.full((4, 4), 60, np.uint8), 0, 5_000, 4.0))  # MSV 2: brighter
    assert cmd.exposure_us * cmd.gain > 5_000 * 4.0 and cmd.exposure_us == 20_000.0


def test_navid_without_gain_stays_at_t_max():
    limits = CameraLimits(10.0, 20_000.0, 1.0)
    trace = closed_loop(NavidController(limits, 1_000.0), SCENE - 2.0, 15)
    assert trace[-1][0] == 20_000 and all(K == 1.0 for _, K, _, _ in trace)


def test_navid_dead_band_no_command():
    limits = CameraLimits()
    ctrl = NavidController(limits, 5_000.0)
    img = np.array([[0, 60, 120, 170, 230, 60, 120, 170, 0, 230]], np.uint8)  # MSV 3 -> acts
    img_ok = np.array([[60, 120]], np.uint8)  # MSV 2.5 -> inside the dead band
    assert ctrl.on_frame(Frame(img_ok, 0, 5_000, 1.0)) is None
    cmd = ctrl.on_frame(Frame(img, 10_000, 15_000, 1.0))
    assert cmd is not None and cmd.exposure_us < 5_000  # too bright -> shorter


def test_navid_mask_selects_region():
    limits = CameraLimits()
    img = np.zeros((4, 4), np.uint8)
    img[:, 2:] = 128  # right half mid-grey (region 2 -> MSV 3), left half black (MSV 1)
    mask = np.zeros((4, 4), np.uint8)
    mask[:, 2:] = 255
    ctrl = NavidController(limits, 5_000.0, options=NavidOptions(mask=mask))
    assert ctrl.options.image_fraction == 0.5 and ctrl.options.k_exposure == 35.0 and ctrl.options.k_gain == 20.0
    cmd = ctrl.on_frame(Frame(img, 0, 5_000, 1.0))
    assert ctrl.last_msv == pytest.approx(3.0) and cmd.exposure_us < 5_000  # unmasked: MSV 2 -> longer
    with pytest.raises(ParameterError, match="mask shape"):
        ctrl.on_frame(Frame(np.zeros((3, 3), np.uint8), 10_000, 15_000, 1.0))


# -------------------------------------------------------------------------------------- builtin
def _two_level(n_a, a, n_b, b):
    return np.array([[a] * n_a + [b] * n_b], np.uint8)


def test_builtin_over_exposed_lowers_by_formula():
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    img = _two_level(60, 250, 40, 100)  # 60 % in the top 10 % of bins (Z >= 230)
    cmd = ctrl.on_frame(Frame(img, 0, 5_000, 1.0))
    expected = 5_000 - math.floor(14000.0 * (0.60 - 0.33) ** 1.65)
    assert cmd.exposure_us == pytest.approx(expected, abs=1)
    assert 5_000 - cmd.exposure_us > 1_000  # ~1614 µs, a big step


def test_builtin_under_exposed_raises_by_formula():
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    img = _two_level(80, 3, 20, 100)  # 80 % in the lowest 10 % of bins (Z <= 24)
    cmd = ctrl.on_frame(Frame(img, 0, 5_000, 1.0))
    expected = 5_000 + math.floor(14000.0 * (0.80 - 0.33) ** 1.65)
    assert cmd.exposure_us == pytest.approx(expected, abs=1)


def test_builtin_msv_branch_by_formula():
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    # all 200: no under/over pixels; value-weighted MSV = 4 (region 3), e = -1.5, divisor 1
    cmd = ctrl.on_frame(Frame(np.full((4, 4), 200, np.uint8), 0, 5_000, 1.0))
    assert cmd.exposure_us == 5_000 - math.floor(100 * 1.5**2)


def _expected_msv_step(img):
    """libcaer's MSV-branch step computed from its definition (values summed per 5 regions)."""
    z = img.astype(np.int64).ravel()
    region = (z << 8) // 13107  # DAVIS pixels are 8-bit values left-shifted to 16 bits
    sums = [z[region == i].sum() for i in range(5)]
    msv = sum((i + 1) * s for i, s in enumerate(sums)) / sum(sums)
    lo, hi = np.mean(z < 25) - 0.33, np.mean(z >= 230) - 0.33
    div = 10 if min(abs(lo), abs(hi)) < 0.05 else 5 if min(abs(lo), abs(hi)) < 0.1 else 1
    e = 2.5 - msv
    return int(100 * e * e) // div * (1 if e > 0 else -1)


@pytest.mark.parametrize("n_bright,n_mid,expected_div", [(0, 100, 1), (20, 80, 1), (25, 75, 5), (30, 70, 10)])
def test_builtin_msv_branch_value_weighted_with_divisor(n_bright, n_mid, expected_div):
    img = _two_level(n_bright, 240, n_mid, 100) if n_bright else _two_level(50, 60, 50, 200)
    step = _expected_msv_step(img)
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    cmd = ctrl.on_frame(Frame(img, 0, 5_000, 1.0))
    assert cmd.exposure_us == 5_000 + step
    if n_bright == 0:  # 60/200 half-half: value-weighted MSV 3.54 (a pixel count would give 3.0)
        assert step == -int(100 * (2.5 - 920 / 260) ** 2)
    else:
        assert (
            abs(step)
            == int(100 * (2.5 - (5 * 240 * n_bright + 2 * 100 * n_mid) / (240 * n_bright + 100 * n_mid)) ** 2)
            // expected_div
        )


@pytest.mark.parametrize("low,high", [(24, 230), (25, 229)])
def test_builtin_histogram_boundaries(low, high):
    """Under: Z <= 24 (lowest int(0.1*256) = 25 bins); over: Z >= 230 (bins from int(0.9*256))."""
    inside = low == 24
    for level, sign in ((low, +1), (high, -1)):
        ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
        img = _two_level(60, level, 40, 100)
        cmd = ctrl.on_frame(Frame(img, 0, 5_000, 1.0))
        big = math.floor(14000.0 * 0.27**1.65)
        if inside:
            assert cmd.exposure_us == 5_000 + sign * big
        else:
            assert cmd.exposure_us == 5_000 + _expected_msv_step(img)


def test_builtin_well_exposed_changes_little():
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    # 11 px of 80 (region 1) and 8 px of 110 (region 2): equal value sums -> MSV exactly 2.5
    img = _two_level(11, 80, 8, 110)
    assert ctrl.on_frame(Frame(img, 0, 5_000, 1.0)) is None
    # a mid-grey textured scene rendered at a sensible exposure: at most a small step
    img = render(SCENE, 5_000, 1.0)
    cmd = ctrl.on_frame(Frame(img, 10_000, 15_000, 1.0))
    assert cmd is None or abs(cmd.exposure_us - 5_000) <= 0.02 * 5_000


def test_builtin_ignores_frames_with_other_exposure():
    ctrl = BuiltinController(CameraLimits(1.0, 1e6, 1.0), 5_000.0)
    over = _two_level(60, 250, 40, 100)
    assert ctrl.on_frame(Frame(over, 0, 4_000, 1.0)) is None  # not the value it set (5000)
    cmd = ctrl.on_frame(Frame(over, 10_000, 15_000, 1.0))
    assert cmd is not None
    # the camera has not caught up yet: another frame at the old 5000 µs is ignored
    assert ctrl.on_frame(Frame(over, 20_000, 25_000, 1.0)) is None
    new_t = int(round(cmd.exposure_us))
    assert ctrl.on_frame(Frame(over, 30_000, 30_000 + new_t, 1.0)) is not None


def test_builtin_clips_to_camera_limits_and_gain_one():
    limits = CameraLimits(100.0, 6_000.0, 4.0)
    ctrl = BuiltinController(limits, 5_900.0, gain=2.0)
    assert ctrl.initial_command().gain == 1.0
    cmd = ctrl.on_frame(Frame(np.zeros((5, 5), np.uint8), 0, 5_900, 1.0))  # all black -> +8k µs
    assert cmd.exposure_us == 6_000.0 and cmd.gain == 1.0


# ---------------------------------------------------------------------------------------- fixed
def test_fixed_never_changes():
    limits = CameraLimits(10.0, 30_000.0, 4.0)
    ctrl = FixedController(limits, 7_000.0, 2.0)
    first = ctrl.initial_command(0)
    assert (first.exposure_us, first.gain) == (7_000.0, 2.0)
    for i, v in enumerate((0, 255, 128)):
        assert ctrl.on_frame(Frame(np.full((4, 4), v, np.uint8), i * 10_000, i * 10_000 + 7_000, 2.0)) is None
    assert ctrl.initial_command(5).exposure_us == 7_000.0
    clamped = FixedController(limits, 1e9, 100.0).initial_command()
    assert (clamped.exposure_us, clamped.gain) == (30_000.0, 4.0)


# ----------------------------------------------------------------------------------- degenerate
CLASSES = [NavidController, BuiltinController, FixedController]


@st.composite
def limits_and_start(draw):
    lo = draw(st.floats(1.0, 1_000.0))
    hi = lo * draw(st.floats(1.0, 1_000.0))
    gmax = draw(st.one_of(st.just(1.0), st.floats(1.0, 16.0)))
    t0 = draw(st.floats(0.5, 2e6))
    g0 = draw(st.floats(0.5, 20.0))
    return CameraLimits(lo, hi, gmax), t0, g0


@st.composite
def images(draw):
    h, w = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    kind = draw(st.sampled_from(["const", "random"]))
    if kind == "const":
        return np.full((h, w), draw(st.sampled_from([0, 1, 24, 25, 128, 229, 230, 254, 255])), np.uint8)
    vals = draw(st.lists(st.integers(0, 255), min_size=h * w, max_size=h * w))
    return np.array(vals, np.uint8).reshape(h, w)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ls=limits_and_start(), imgs=st.lists(images(), min_size=1, max_size=6))
def test_commands_always_valid(ls, imgs):
    limits, t0, g0 = ls
    for cls in CLASSES:
        ctrl = cls(limits, t0, g0)
        cmd = ctrl.initial_command(0)
        check_command(cmd, limits)
        t = 0
        for i, img in enumerate(imgs):
            T = max(1, int(round(cmd.exposure_us)))
            new = ctrl.on_frame(Frame(img, t, t + T, cmd.gain, i))
            if new is not None:
                check_command(new, limits)
                cmd = new
            t += T + 1


@pytest.mark.parametrize("value", [0, 255, 128])
@pytest.mark.parametrize("gain_max", [1.0, 8.0])
@pytest.mark.parametrize("shape", [(1, 1), (20, 30)])
def test_degenerate_images_repeated(value, gain_max, shape):
    limits = CameraLimits(10.0, 30_000.0, gain_max)
    for cls in CLASSES:
        for t0 in (10.0, 30_000.0):
            ctrl = cls(limits, t0)
            cmd = ctrl.initial_command()
            for i in range(30):  # driven into the limits by a constant image
                T = max(1, int(round(cmd.exposure_us)))
                new = ctrl.on_frame(Frame(np.full(shape, value, np.uint8), i * 100_000, i * 100_000 + T, cmd.gain, i))
                if new is not None:
                    check_command(new, limits)
                    cmd = new
            if cls is NavidController and value == 0:
                assert cmd.exposure_us == 30_000.0 and cmd.gain == gain_max  # all black: everything up
            if cls is NavidController and value == 255:
                assert cmd.exposure_us == 10.0 and cmd.gain == 1.0


# ------------------------------------------------------------------------------- bad parameters
LIM = CameraLimits()


@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize(
    "kw", [dict(exposure_us=math.nan), dict(exposure_us=-5.0), dict(gain=math.nan), dict(gain=0.0)]
)
def test_bad_common_parameters(cls, kw):
    with pytest.raises(ParameterError):
        cls(LIM, **kw)


@pytest.mark.parametrize(
    "kw",
    [
        dict(target_msv=math.nan),
        dict(target_msv=1.0),
        dict(target_msv=5.5),
        dict(image_fraction=0.0),
        dict(image_fraction=1.5),
        dict(k_exposure=-1.0),
        dict(k_gain=math.inf),
        dict(ki_ratio=-0.1),
        dict(integral_limit=math.nan),
        dict(ev_per_unit=0.0),
        dict(ev_per_unit=1.0),
        dict(dead_band=-0.1),
        dict(dead_band=1.0),
        dict(mask=np.zeros((3, 3))),
        dict(mask=-np.ones((3, 3))),
        dict(mask=np.full((3, 3), np.nan)),
        dict(mask=np.ones(3)),
        dict(k_exposure="50"),
    ],
)
def test_navid_bad_parameters(kw):
    with pytest.raises(ParameterError):
        NavidOptions(**kw)


def test_bad_limits_type():
    for cls in CLASSES:
        with pytest.raises(ParameterError):
            cls((10.0, 30_000.0, 1.0))
