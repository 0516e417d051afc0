"""The DVS bias encoding (against libcaer's documented words) and the bias model's mapping and refusals."""

import math

import pytest

from necviz.core.biases import (
    BIAS_ADDRESSES,
    COARSE_CURRENT_PA,
    BiasModel,
    CoarseFine,
    DvsBiases,
    DvsSettings,
    DvsState,
    coarse_fine_for_current,
    physical_settings,
    threshold_logs,
)
from necviz.core.errors import ParameterError
from necviz.drivers.davis import protocol as P

REF = DvsSettings(0.26, 0.24, 100.0, 300.0)


def test_coarse_fine_word_layout_matches_libcaer():
    # caerBiasCoarseFineGenerate: enabled bit0, sexN bit1, typeNormal bit2, currentLevelNormal bit3,
    # fine << 4, coarse << 12. DiffBn N-type (4, 39): 0x4000 | 39 << 4 | 0xF
    assert CoarseFine(4, 39).word() == 0x4000 | (39 << 4) | 0xF == 0x427F
    # P-type (sexN off) PrBp (2, 58): 0x2000 | 58 << 4 | 0b1101
    assert CoarseFine(2, 58, sex_n=False).word() == 0x2000 | (58 << 4) | 0xD
    # PADFOLLBN N-off (7, 215): enabled bit clear
    assert CoarseFine(7, 215, enabled=False).word() == 0x7000 | (215 << 4) | 0xE
    for w in (0x427F, 0x23AD, 0x7D7E, 0x0000, 0xFFFF & 0x7FFF):
        assert CoarseFine.parse(w).word() == w


def test_encoding_agrees_with_driver_default_tables():
    # the driver's tables (drivers/davis/protocol.py) were written from libcaer's davis_common.h; the model's
    # defaults and addresses must give exactly the same words at the same addresses
    for family, table in (("DAVIS346", P.DAVIS346_BIASES), ("DAVIS240", P.DAVIS240_BIASES)):
        words = DvsBiases.defaults(family).words(family)
        assert set(words) <= set(table)
        assert words == {a: table[a] for a in words}
        for name, addr in BIAS_ADDRESSES[family].items():
            assert addr in table, name
            assert CoarseFine.parse(table[addr]).word() == table[addr]
    # documented defaults spelled out once more, independently: DAVIS346 DiffBn N(4,39), OnBn N(5,255), OffBn N(4,1)
    b = DvsBiases.from_words(P.DAVIS346_BIASES)
    assert (b.diff.coarse, b.diff.fine, b.on.coarse, b.on.fine, b.off.coarse, b.off.fine) == (4, 39, 5, 255, 4, 1)
    assert (b.refr.coarse, b.refr.fine, b.refr.sex_n) == (4, 25, False)


def test_current_from_and_to_coarse_fine_as_libcaer():
    assert CoarseFine(4, 39).current_pa == pytest.approx(48437 * 39 / 255)
    assert coarse_fine_for_current(48437 * 39 / 255) == (4, 39)
    assert coarse_fine_for_current(24.8e6 * 3) == (7, 255)  # limited to 24.8 µA
    assert coarse_fine_for_current(0.001) == (0, 1)  # fine kept >= 1
    assert coarse_fine_for_current(COARSE_CURRENT_PA[3] + 1)[0] == 4  # smallest range that holds it


def test_model_at_defaults_and_physical_estimate():
    m = BiasModel(reference=REF)
    assert m.settings(m.defaults) == REF
    phys = physical_settings(m.defaults)
    # Nozaki & Delbruck's prefactor with kappa 0.7, C1/C2 = 20 puts libcaer's defaults near the nominal DAVIS346
    assert 0.2 < phys.c_on < 0.35 and 0.2 < phys.c_off < 0.35
    # jAER DavisConfig's estimates at libcaer's defaults: T = 20 fF x 0.8 V / I(RefrBp 4/25),
    # f = I(PrSFBp 1/16) / (2 pi 25 mV 131.167 fF)
    assert phys.refractory_us == pytest.approx(20e-15 * 0.8 / (48437 * 25 / 255 * 1e-12) * 1e6)
    assert phys.bandwidth_hz == pytest.approx(94 * 16 / 255 * 1e-12 / (2 * math.pi * 25e-3 * 131.167e-15))
    assert 3 < phys.refractory_us < 4 and 250 < phys.bandwidth_hz < 320
    # PrBp only matters once the follower's current exceeds half the photoreceptor's
    st = DvsState(BiasModel(reference=REF))
    assert st.request("bias.PrBp", "2/20").settings().bandwidth_hz == pytest.approx(300.0)
    assert st.request("bias.PrBp", "0/200").settings().bandwidth_hz < 300.0
    on, off = threshold_logs(m.defaults)
    assert on == pytest.approx(math.log(387500 / (48437 * 39 / 255)))
    assert off == pytest.approx(math.log(39.0))


@pytest.mark.parametrize(
    "key, value",
    [("c_on", 0.15), ("c_on", 0.4), ("c_off", 0.15), ("c_off", 0.5), ("refractory_us", 30.0), ("bandwidth_hz", 900.0)],
)
def test_solve_reaches_the_request_within_quantisation(key, value):
    st = DvsState(BiasModel(reference=REF))
    ch = st.request(key, value)
    got = getattr(ch.settings(), key)
    assert got == pytest.approx(value, rel=0.01)
    moved = ch.words()
    assert moved  # at least one bias word moves, and only the ones the control owns
    names = {BIAS_ADDRESSES["DAVIS346"].get(n): n for n in ("ONBN", "OFFBN", "REFRBP", "PRBP", "PRSFBP")}
    owner = {"c_on": {"ONBN"}, "c_off": {"OFFBN"}, "refractory_us": {"REFRBP"}, "bandwidth_hz": {"PRBP", "PRSFBP"}}
    assert {names[a] for a in moved} <= owner[key]
    # nothing changes until applied
    assert st.settings() == REF
    st.apply(ch)
    assert getattr(st.settings(), key) == pytest.approx(value, rel=0.01)


def test_lower_threshold_means_on_current_closer_to_diff():
    st = DvsState(BiasModel(reference=REF))
    b = st.request("c_on", 0.15).biases
    assert st.biases.diff.current_pa < b.on.current_pa < st.biases.on.current_pa


@pytest.mark.parametrize(
    "key, value, text",
    [
        ("c_on", -3, "must be a positive number"),
        ("c_on", "abc", "must be a positive number"),
        ("c_on", float("nan"), "must be a positive number"),
        ("c_on", 5.0, "nearest reachable: 0.533"),
        ("c_off", 3.0, "nearest reachable: 0.78"),
        ("refractory_us", 1e12, "nearest reachable"),
        ("bias.NoSuch", "1/2", "no coarse/fine bias"),
        ("bias.DiffBn", "8/3", "COARSE is 0..7"),
        ("bias.DiffBn", "4", "COARSE/FINE"),
        ("bias.OnBn", "4/30", "OnBn must stay above DiffBn"),
        ("c_on", 0.005, "nearest reachable: 0.01"),
        ("ba_filter_us", 5e6, "nearest reachable: 1023750"),
        ("ba_filter_us", -1, "0 = off"),
        ("gain", 2, "unknown DVS control"),
    ],
)
def test_refusals_are_one_line_and_change_nothing(key, value, text):
    st = DvsState(BiasModel(reference=REF))
    before = (st.biases, st.ba_filter_steps, st.refractory_filter_steps)
    with pytest.raises(ParameterError) as e:
        st.request(key, value)
    assert text in str(e.value) and "\n" not in str(e.value)
    assert (st.biases, st.ba_filter_steps, st.refractory_filter_steps) == before


def test_raw_bias_and_filters():
    st = DvsState(BiasModel(reference=REF))
    ch = st.request("bias.DiffBn", "4/50")  # one of the six: the model follows (both thresholds move)
    assert ch.words() == {10: CoarseFine(4, 50).word()}
    s = ch.settings()
    assert s.c_on < REF.c_on and s.c_off > REF.c_off
    ch = st.request("bias.AEPDBN", "6/90")  # outside the model: written with libcaer's flags for it
    assert ch.words() == {23: CoarseFine(6, 90).word()}
    ch = st.request("bias.PrBp", "3/10")
    assert ch.words() == {14: CoarseFine(3, 10, sex_n=False).word()}
    ch = st.request("ba_filter_us", 1000)
    assert ch.filters == {"ba_filter_us": 4} and ch.words() == {}
    st.apply(ch)
    assert st.ba_filter_steps == 4


def test_davis240_addresses():
    st = DvsState(BiasModel("DAVIS240C", reference=REF))
    assert set(st.request("c_on", 0.2).words()) == {1}  # DAVIS240 ONBN is 1
    # DAVIS240's default OffBn is (4, 0), fine 0: taken as one fine step, so its OFF threshold is the DAVIS346's
    assert threshold_logs(DvsBiases.defaults("DAVIS240")) == threshold_logs(DvsBiases.defaults("DAVIS346"))
    assert st.request("c_off", 0.15).settings().c_off == pytest.approx(0.15, rel=0.01)
