"""DVS biases: the coarse/fine bias words of the DAVIS chips and what they do to the pixel.

Two halves, both pure (no device, no I/O):

**Encoding** (facts of the chip, from libcaer's public source, github.com/inivation/libcaer 3.x):

* A coarse/fine bias word is ``bit0 enabled | bit1 sexN | bit2 typeNormal | bit3 currentLevelNormal |
  fine (8 bits) << 4 | coarse (3 bits) << 12`` (``src/davis.c``: ``caerBiasCoarseFineGenerate``,
  ``caerBiasCoarseFineParse``).
* Its current is ``I = C[coarse] * fine / 255`` with the coarse table ``C`` (pA)
  :data:`COARSE_CURRENT_PA` (``src/davis.c``: ``coarseCurrents``, ``caerBiasCoarseFineToCurrent``); a
  current is turned into a setting with the smallest coarse range that holds it and the rounded fine
  value, 1..255 (``caerBiasCoarseFineFromCurrent``) — :func:`coarse_fine_for_current`.
* The bias addresses of module 5 (``DAVIS346_CONFIG_BIAS_*`` and ``DAVIS240_CONFIG_BIAS_*`` in
  ``include/libcaer/devices/davis.h``) and libcaer's default settings of the six biases that shape the
  DVS pixel (``src/davis_common.h``: ``davisCommonSendDefaultChipConfig``): :data:`BIAS_ADDRESSES`,
  :data:`DEFAULT_DVS_BIASES`.

**Model** (an estimate; a per-camera calibration refines it — ``necviz calibrate`` at the new setting):

* Contrast thresholds (Nozaki & Delbruck, "Temperature and Parasitic Photocurrent Effects in Dynamic
  Vision Sensors", IEEE TED 64(8), 2017, Eq. 2-3; jAER's ``DavisConfig.getOnThresholdLogE`` and
  ``getOffThresholdLogE`` compute the same with ``kappa_n = kappa_p = 0.7`` and ``C1/C2 = 20``)::

      theta_on  = (kappa_n / kappa_p^2) * (C2 / C1) * ln(I_on  / I_diff)
      theta_off = (kappa_n / kappa_p^2) * (C2 / C1) * ln(I_diff / I_off)

  with ``I_diff, I_on, I_off`` the DiffBn, OnBn and OffBn currents. The prefactor (~0.07) varies per chip
  and with temperature, so necviz uses only the model's *ratios*: a camera whose calibrated thresholds at
  libcaer's default biases are ``c_on0, c_off0`` (its profile) has
  ``c_on = c_on0 * ln(I_on/I_diff) / ln(I_on0/I_diff0)`` at other biases (and likewise OFF). Requests move
  OnBn (ON) or OffBn (OFF) and keep DiffBn, so each threshold changes alone.
* Refractory period: RefrBp's current recharges the pixel's reset node after an event, so the dead time is
  ``T = C * dV / I_refr`` (Lichtsteiner, Posch & Delbruck, IEEE JSSC 43(2), 2008; jAER's
  ``DavisConfig.getRefractoryPeriodS`` with C = 20 fF, dV = 0.8 V): ``T = T0 * I_refr0 / I_refr``.
* Bandwidth: the photoreceptor's source follower (PrSFBp) sets the cut-off in bright light,
  ``f = I_sf / (2 pi U_T C1)`` (jAER's ``DavisConfig.getPhotoreceptorSourceFollowerBandwidthHz``, C1 = 131 fF,
  U_T = 25 mV), valid while ``I_sf < I_pr / 2``; beyond that the photoreceptor (PrBp) limits it, taken here as
  ``f ∝ min(I_sf, I_pr / 2)``: ``f = f0 * min(I_sf, I_pr/2) / min(I_sf0, I_pr0/2)``. A request scales both
  currents by ``f/f0``. In dim light the photocurrent, not the bias, limits the bandwidth (the simulator
  models that).
* ``T0`` and ``f0`` (the refractory period and bandwidth at libcaer's defaults) come from the reference: a
  camera's are jAER's estimates (3.4 µs, 287 Hz: :func:`physical_settings`); the simulated DAVIS346's are its
  own parameters (100 µs, 300 Hz), which the emulated camera and the simulator scale.

Limits: a request the bias currents cannot reach (e.g. an ON threshold needing more than 24.8 µA of OnBn)
is refused with the nearest reachable value; quantisation to 255 fine steps moves a threshold by well under
1 % (the value the biases actually give is what is reported and what P-TEDI follows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from necviz.core.checks import format_number
from necviz.core.errors import ParameterError

#: Coarse current table (pA): libcaer ``src/davis.c`` ``coarseCurrents``; ``I = C[coarse] * fine / 255``.
COARSE_CURRENT_PA = (11, 94, 756, 6054, 48437, 387500, 3100000, 24800000)
FINE_MAX = 255
#: the largest and smallest non-zero currents a coarse/fine bias reaches (pA)
CURRENT_MAX_PA = float(COARSE_CURRENT_PA[-1])
CURRENT_MIN_PA = COARSE_CURRENT_PA[0] / FINE_MAX

#: Module-5 bias addresses per chip family (libcaer ``include/libcaer/devices/davis.h``, ``*_CONFIG_BIAS_*``):
#: only the coarse/fine biases (the VDAC and shifted-source ones have other words).
BIAS_ADDRESSES = {
    "DAVIS346": {
        "LOCALBUFBN": 8,
        "PADFOLLBN": 9,
        "DIFFBN": 10,
        "ONBN": 11,
        "OFFBN": 12,
        "PIXINVBN": 13,
        "PRBP": 14,
        "PRSFBP": 15,
        "REFRBP": 16,
        "READOUTBUFBP": 17,
        "APSROSFBN": 18,
        "ADCCOMPBP": 19,
        "COLSELLOWBN": 20,
        "DACBUFBP": 21,
        "LCOLTIMEOUTBN": 22,
        "AEPDBN": 23,
        "AEPUXBP": 24,
        "AEPUYBP": 25,
        "IFREFRBN": 26,
        "IFTHRBN": 27,
        "BIASBUFFER": 34,
    },
    "DAVIS240": {
        "DIFFBN": 0,
        "ONBN": 1,
        "OFFBN": 2,
        "APSCASEPC": 3,
        "DIFFCASBNC": 4,
        "APSROSFBN": 5,
        "LOCALBUFBN": 6,
        "PIXINVBN": 7,
        "PRBP": 8,
        "PRSFBP": 9,
        "REFRBP": 10,
        "AEPDBN": 11,
        "LCOLTIMEOUTBN": 12,
        "AEPUXBP": 13,
        "AEPUYBP": 14,
        "IFTHRBN": 15,
        "IFREFRBN": 16,
        "PADFOLLBN": 17,
        "APSOVERFLOWLEVELBN": 18,
        "BIASBUFFER": 19,
    },
}
#: the six biases that shape the DVS pixel, in :class:`DvsBiases` field order
DVS_BIAS_NAMES = ("DIFFBN", "ONBN", "OFFBN", "REFRBP", "PRBP", "PRSFBP")


@dataclass(frozen=True)
class CoarseFine:
    """One coarse/fine bias: ``coarse`` 0..7, ``fine`` 0..255 and the four flag bits of the word."""

    coarse: int
    fine: int
    enabled: bool = True
    sex_n: bool = True
    type_normal: bool = True
    current_level_normal: bool = True

    def __post_init__(self) -> None:
        if not (0 <= self.coarse <= 7 and 0 <= self.fine <= FINE_MAX):
            raise ParameterError(f"a coarse/fine bias is COARSE 0..7 / FINE 0..255, got {self.coarse}/{self.fine}")

    def word(self) -> int:
        """The 16-bit word (libcaer ``caerBiasCoarseFineGenerate``)."""
        return (
            int(self.enabled)
            | int(self.sex_n) << 1
            | int(self.type_normal) << 2
            | int(self.current_level_normal) << 3
            | (self.fine & 0xFF) << 4
            | (self.coarse & 0x7) << 12
        )

    @classmethod
    def parse(cls, word: int) -> CoarseFine:
        """Inverse of :meth:`word` (libcaer ``caerBiasCoarseFineParse``)."""
        w = int(word)
        return cls((w >> 12) & 0x7, (w >> 4) & 0xFF, bool(w & 1), bool(w & 2), bool(w & 4), bool(w & 8))

    @property
    def current_pa(self) -> float:
        """``C[coarse] * fine / 255`` (pA; libcaer ``caerBiasCoarseFineToCurrent`` before its rounding)."""
        return COARSE_CURRENT_PA[self.coarse] * self.fine / FINE_MAX

    def with_current(self, pa: float) -> CoarseFine:
        """The setting nearest ``pa`` (:func:`coarse_fine_for_current`), flags kept."""
        c, f = coarse_fine_for_current(pa)
        return replace(self, coarse=c, fine=f)

    def __str__(self) -> str:
        return f"{self.coarse}/{self.fine}"


def coarse_fine_for_current(pa: float) -> tuple[int, int]:
    """``(coarse, fine)`` for a current in pA: the smallest coarse range holding it, fine rounded and kept in
    1..255 (libcaer ``caerBiasCoarseFineFromCurrent``; above 24.8 µA the largest setting)."""
    pa = min(float(pa), CURRENT_MAX_PA)
    coarse = next((i for i, c in enumerate(COARSE_CURRENT_PA) if pa <= c), 7)
    fine = min(max(round(FINE_MAX * pa / COARSE_CURRENT_PA[coarse]), 1), FINE_MAX)
    return coarse, fine


def _n(c, f, **kw):
    return CoarseFine(c, f, sex_n=True, **kw)


def _p(c, f):
    return CoarseFine(c, f, sex_n=False)


@dataclass(frozen=True)
class DvsBiases:
    """The six biases of the DVS pixel (DiffBn, OnBn, OffBn, RefrBp, PrBp, PrSFBp)."""

    diff: CoarseFine
    on: CoarseFine
    off: CoarseFine
    refr: CoarseFine
    pr: CoarseFine
    prsf: CoarseFine

    @classmethod
    def defaults(cls, family: str = "DAVIS346") -> DvsBiases:
        """libcaer's defaults (``src/davis_common.h``, ``davisCommonSendDefaultChipConfig``)."""
        return DEFAULT_DVS_BIASES[family_of(family)]

    @classmethod
    def from_words(cls, words: dict[int, int], family: str = "DAVIS346") -> DvsBiases:
        """From module-5 words (parameter -> word); biases missing from ``words`` keep libcaer's defaults."""
        fam = family_of(family)
        d, a = DEFAULT_DVS_BIASES[fam], BIAS_ADDRESSES[fam]
        vals = [
            CoarseFine.parse(words[a[name]]) if a[name] in words else getattr(d, f)
            for name, f in zip(DVS_BIAS_NAMES, _FIELDS, strict=True)
        ]
        return cls(*vals)

    def words(self, family: str = "DAVIS346") -> dict[int, int]:
        """Module-5 parameter -> word of the six biases."""
        a = BIAS_ADDRESSES[family_of(family)]
        return {a[name]: getattr(self, f).word() for name, f in zip(DVS_BIAS_NAMES, _FIELDS, strict=True)}


_FIELDS = ("diff", "on", "off", "refr", "pr", "prsf")

DEFAULT_DVS_BIASES = {
    # DAVIS346: DIFFBN N(4,39), ONBN N(5,255), OFFBN N(4,1), REFRBP P(4,25), PRBP P(2,58), PRSFBP P(1,16)
    "DAVIS346": DvsBiases(_n(4, 39), _n(5, 255), _n(4, 1), _p(4, 25), _p(2, 58), _p(1, 16)),
    # DAVIS240 (IS_DAVIS240 branch): the same except OFFBN N(4,0)
    "DAVIS240": DvsBiases(_n(4, 39), _n(5, 255), _n(4, 0), _p(4, 25), _p(2, 58), _p(1, 16)),
}


def family_of(chip: str) -> str:
    """``"DAVIS346"`` or ``"DAVIS240"`` for a chip or family name (DAVIS346B, DAVIS240C, ...)."""
    name = str(chip or "DAVIS346").upper()
    if name.startswith("DAVIS240"):
        return "DAVIS240"
    if name.startswith("DAVIS346") or name in ("DAVIS", "SIM"):
        return "DAVIS346"
    raise ParameterError(f"no bias model for {chip!r} (DAVIS346 and DAVIS240 have one)")


# -- the model ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DvsSettings:
    """What the biases give, in the camera's units: thresholds (ln), refractory period (µs), bandwidth (Hz)."""

    c_on: float
    c_off: float
    refractory_us: float
    bandwidth_hz: float

    def as_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in ("c_on", "c_off", "refractory_us", "bandwidth_hz")}


#: the model's physical prefactor (kappa_n / kappa_p^2) * (C2 / C1) for kappa = 0.7, C1/C2 = 20 (jAER's estimate)
THRESHOLD_PREFACTOR = 0.7 / 0.7**2 / 20.0
#: the smallest threshold necviz sets (ln): below it a pixel fires on its own noise (the simulator's and v2e's
#: per-pixel clamp is the same 0.01)
THRESHOLD_FLOOR = 0.01
#: refractory charge C * dV (C): 20 fF x 0.8 V (jAER ``DavisConfig``, "guesstimated")
REFRACTORY_CHARGE_C = 20e-15 * 0.8
#: photoreceptor load capacitance C1 (F) and the thermal voltage U_T (V) (jAER ``DavisConfig``)
PHOTORECEPTOR_C1_F = 131.167e-15
THERMAL_VOLTAGE_V = 25e-3


def _current_or_step(cf: CoarseFine) -> float:
    """A bias's current, with a zero fine value taken as one fine step of its coarse range: DAVIS240's
    default OffBn is (4, 0) and its OFF events still fire, so the model treats it as (4, 1), as on the DAVIS346."""
    return cf.current_pa if cf.fine > 0 else COARSE_CURRENT_PA[cf.coarse] / FINE_MAX


def threshold_logs(b: DvsBiases) -> tuple[float, float]:
    """``ln(I_on / I_diff)`` and ``ln(I_diff / I_off)`` (<= 0: that polarity no longer fires)."""
    i_d, i_on, i_off = (_current_or_step(x) for x in (b.diff, b.on, b.off))
    return math.log(i_on / i_d), math.log(i_d / i_off)


def _bandwidth_current(b: DvsBiases) -> float:
    """The current that sets the cut-off: the source follower's, or half the photoreceptor's when that is less."""
    return min(_current_or_step(b.prsf), 0.5 * _current_or_step(b.pr))


def physical_settings(b: DvsBiases) -> DvsSettings:
    """The model's absolute estimate at ``b`` with jAER's constants (``DavisConfig``: thresholds from
    :data:`THRESHOLD_PREFACTOR`, ``T = C dV / I_refr``, ``f = I / (2 pi U_T C1)``)."""
    on, off = threshold_logs(b)
    i_refr = _current_or_step(b.refr) * 1e-12
    i_bw = _bandwidth_current(b) * 1e-12
    return DvsSettings(
        THRESHOLD_PREFACTOR * on,
        THRESHOLD_PREFACTOR * off,
        REFRACTORY_CHARGE_C / i_refr * 1e6,
        i_bw / (2 * math.pi * THERMAL_VOLTAGE_V * PHOTORECEPTOR_C1_F),
    )


#: keys of the named controls (``dvs.KEY``), with unit and meaning
CONTROLS = {
    "c_on": "ln: ON contrast threshold (moves OnBn)",
    "c_off": "ln: OFF contrast threshold (moves OffBn)",
    "refractory_us": "µs: pixel refractory period (moves RefrBp)",
    "bandwidth_hz": "Hz: photoreceptor bandwidth in bright light (moves PrBp and PrSFBp together)",
    "refractory_filter_us": "µs: the FPGA's refractory filter (0 = off; 250 µs steps)",
    "ba_filter_us": "µs: the FPGA's background-activity filter (0 = off; 250 µs steps)",
}
#: the FPGA filters' time registers: 250 µs units, 0..4095 (libcaer ``davis.h``, DVS params 32 and 34)
FILTER_STEP_US = 250
FILTER_MAX_STEPS = 4095


@dataclass(frozen=True)
class BiasModel:
    """The model of the module docstring, anchored at ``reference``: the camera's settings at libcaer's
    default biases (its calibrated thresholds; ``None``: the model's physical estimate and the anchors)."""

    family: str = "DAVIS346"
    reference: DvsSettings | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "family", family_of(self.family))
        if self.reference is None:
            object.__setattr__(self, "reference", physical_settings(DEFAULT_DVS_BIASES[self.family]))

    @property
    def defaults(self) -> DvsBiases:
        return DEFAULT_DVS_BIASES[self.family]

    @property
    def ref(self) -> DvsSettings:
        """The settings at libcaer's default biases (``reference``, filled in by the constructor)."""
        assert self.reference is not None
        return self.reference

    def ratios(self, b: DvsBiases) -> DvsSettings:
        """Each setting at ``b`` over its value at libcaer's defaults (1 at the defaults)."""
        d = self.defaults
        on0, off0 = threshold_logs(d)
        on, off = threshold_logs(b)
        refr = _current_or_step(d.refr) / _current_or_step(b.refr)
        return DvsSettings(on / on0, off / off0, refr, _bandwidth_current(b) / _bandwidth_current(d))

    def settings(self, b: DvsBiases) -> DvsSettings:
        """What the biases ``b`` give (reference x the model's ratio)."""
        r, ref = self.ratios(b), self.ref
        return DvsSettings(
            ref.c_on * r.c_on,
            ref.c_off * r.c_off,
            ref.refractory_us * r.refractory_us,
            ref.bandwidth_hz * r.bandwidth_hz,
        )

    def reachable(self, key: str, b: DvsBiases) -> tuple[float, float]:
        """The range of ``key`` the biases reach from ``b`` (the other biases kept)."""
        ref, d = self.ref, self.defaults
        on0, off0 = threshold_logs(d)
        i_d = _current_or_step(b.diff)
        if key == "c_on":
            return max(THRESHOLD_FLOOR, _step_above(i_d, ref.c_on / on0)), ref.c_on * math.log(
                CURRENT_MAX_PA / i_d
            ) / on0
        if key == "c_off":
            lo = max(THRESHOLD_FLOOR, _step_above(i_d, ref.c_off / off0, below=True))
            return lo, ref.c_off * math.log(i_d / CURRENT_MIN_PA) / off0
        if key == "refractory_us":
            q = ref.refractory_us * d.refr.current_pa
            return q / CURRENT_MAX_PA, q / CURRENT_MIN_PA
        if key == "bandwidth_hz":
            lo = max(CURRENT_MIN_PA / d.pr.current_pa, CURRENT_MIN_PA / d.prsf.current_pa)
            hi = min(CURRENT_MAX_PA / d.pr.current_pa, CURRENT_MAX_PA / d.prsf.current_pa)
            return ref.bandwidth_hz * lo, ref.bandwidth_hz * hi
        raise ParameterError(f"unknown DVS control {key!r}; controls: {', '.join(CONTROLS)}")

    def solve(self, key: str, value: float, b: DvsBiases, reach: bool = True) -> DvsBiases:
        """The biases that give ``key = value`` from ``b`` (one or two biases move; the rest are kept).

        Raises :class:`ParameterError` (one line) for a value that is not a positive number, or one the
        biases cannot reach, naming the nearest reachable value (``reach=False``: the nearest is taken instead).
        """
        v = _positive(f"dvs.{key}", value)
        lo, hi = self.reachable(key, b)
        if not reach:
            v = min(max(v, lo), hi)
        if not lo <= v <= hi:
            near = lo if v < lo else hi
            raise ParameterError(
                f"dvs.{key} = {format_number(v)} is beyond what the {self.family}'s biases reach "
                f"({_fmt(lo)}..{_fmt(hi)}); nearest reachable: {_fmt(near)}"
            )
        ref, d = self.ref, self.defaults
        on0, off0 = threshold_logs(d)
        i_d = _current_or_step(b.diff)
        if key == "c_on":
            return replace(b, on=b.on.with_current(i_d * math.exp(v / ref.c_on * on0)))
        if key == "c_off":
            return replace(b, off=b.off.with_current(i_d * math.exp(-v / ref.c_off * off0)))
        if key == "refractory_us":
            return replace(b, refr=b.refr.with_current(d.refr.current_pa * ref.refractory_us / v))
        r = v / ref.bandwidth_hz  # bandwidth_hz: both currents scaled from the defaults
        return replace(b, pr=b.pr.with_current(d.pr.current_pa * r), prsf=b.prsf.with_current(d.prsf.current_pa * r))


def _step_above(i_d: float, scale: float, below: bool = False) -> float:
    """The smallest threshold above zero: one fine step of the bias next to DiffBn's current."""
    c, f = coarse_fine_for_current(i_d)
    nxt = COARSE_CURRENT_PA[c] * (f - 1 if below else f + 1) / FINE_MAX
    if nxt <= 0 or nxt > CURRENT_MAX_PA:
        return 0.0
    return scale * abs(math.log(nxt / i_d))


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{name} must be a positive number, got {format_number(v)}")
    return v


def parse_coarse_fine(name: str, text) -> tuple[int, int]:
    """``"COARSE/FINE"`` (e.g. ``"4/39"``) -> ``(4, 39)``; one-line error otherwise."""
    parts = str(text).strip().split("/")
    try:
        c, f = (int(p) for p in parts)
    except ValueError:
        raise ParameterError(f"bias.{name} takes COARSE/FINE (e.g. 4/39), got {text!r}") from None
    if not (0 <= c <= 7 and 0 <= f <= FINE_MAX):
        raise ParameterError(f"bias.{name} = {text}: COARSE is 0..7 and FINE 0..255")
    return c, f


def filter_steps(name: str, value) -> int:
    """An FPGA filter time (µs, 0 = off) -> 250 µs steps 0..4095 (refused when out of range or not a number)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"dvs.{name} must be a time in µs (0 = off), got {value!r}") from None
    if not math.isfinite(v) or v < 0:
        raise ParameterError(f"dvs.{name} must be a time in µs (0 = off), got {format_number(v)}")
    steps = round(v / FILTER_STEP_US)
    if v > 0 and steps == 0:
        steps = 1
    if steps > FILTER_MAX_STEPS:
        raise ParameterError(
            f"dvs.{name} = {format_number(v)} µs is beyond the filter's range; nearest reachable: "
            f"{FILTER_MAX_STEPS * FILTER_STEP_US} µs"
        )
    return steps


@dataclass
class DvsState:
    """The DVS settings of one camera as necviz set them: the six biases, the FPGA filters, and the model.

    :meth:`request` turns one control (``dvs.KEY`` or ``bias.NAME``) into a :class:`DvsChange` without
    changing anything; :meth:`apply` commits it (after the camera took it).
    """

    model: BiasModel = field(default_factory=BiasModel)
    biases: DvsBiases | None = None
    #: FPGA filters in 250 µs steps (0 = off): background activity, refractory. libcaer's defaults: BA on at
    #: 8 steps (2 ms), refractory off (``davisCommonSendDefaultFPGAConfig``).
    ba_filter_steps: int = 8
    refractory_filter_steps: int = 0

    def __post_init__(self) -> None:
        if self.biases is None:
            self.biases = self.model.defaults

    @property
    def current(self) -> DvsBiases:
        """The biases now (``biases``, never ``None`` after construction)."""
        assert self.biases is not None
        return self.biases

    @property
    def family(self) -> str:
        return self.model.family

    def settings(self) -> DvsSettings:
        return self.model.settings(self.current)

    def request(self, key: str, value, reach: bool = True) -> DvsChange:
        """The change that sets ``key`` (``c_on``, ``c_off``, ``refractory_us``, ``bandwidth_hz``,
        ``ba_filter_us``, ``refractory_filter_us`` or ``bias.NAME``) to ``value`` (a number, or ``"C/F"``).
        ``reach=False`` checks everything but whether the biases reach the value (a check before the camera's
        reference is known)."""
        key = str(key)
        if key.startswith("dvs."):
            key = key[4:]
        if key.startswith("bias."):
            name = key[5:].upper()
            addr = BIAS_ADDRESSES[self.family].get(name)
            if addr is None:
                raise ParameterError(
                    f"no coarse/fine bias {key[5:]!r} on the {self.family}; biases: "
                    + ", ".join(BIAS_ADDRESSES[self.family])
                )
            c, f = parse_coarse_fine(key[5:], value)
            if name in DVS_BIAS_NAMES:
                fld = _FIELDS[DVS_BIAS_NAMES.index(name)]
                b = replace(self.current, **{fld: replace(getattr(self.current, fld), coarse=c, fine=f)})
                got = self.model.settings(b)
                if min(got.c_on, got.c_off) < THRESHOLD_FLOOR:
                    raise ParameterError(
                        f"bias.{name} = {c}/{f} leaves a contrast threshold at {min(got.c_on, got.c_off):.3g} "
                        f"(OnBn must stay above DiffBn and OffBn below it; the smallest threshold set is "
                        f"{THRESHOLD_FLOOR:g})"
                    )
                return DvsChange(self, f"bias.{name}", f"{c}/{f}", biases=b)
            return DvsChange(self, f"bias.{name}", f"{c}/{f}", raw={addr: (c, f)})
        if key in ("ba_filter_us", "refractory_filter_us"):
            steps = filter_steps(key, value)
            return DvsChange(self, key, steps * FILTER_STEP_US, filters={key: steps})
        if key not in CONTROLS:
            raise ParameterError(f"unknown DVS control {key!r}; controls: {', '.join(CONTROLS)}, bias.NAME")
        return DvsChange(
            self,
            key,
            format_number(float(value)) if _isnum(value) else value,
            biases=self.model.solve(key, value, self.current, reach),
        )

    def apply(self, change: DvsChange) -> None:
        if change.biases is not None:
            self.biases = change.biases
        for k, v in change.filters.items():
            setattr(self, k.replace("_us", "_steps"), v)


def _isnum(v) -> bool:
    try:
        float(v)
        return True
    except (TypeError, ValueError):
        return False


@dataclass
class DvsChange:
    """One requested change: the new biases (and the words that differ), FPGA filter steps, or a raw bias."""

    state: DvsState
    key: str
    value: object
    biases: DvsBiases | None = None
    filters: dict = field(default_factory=dict)
    raw: dict = field(default_factory=dict)  # address -> (coarse, fine) of a bias outside the model

    def words(self) -> dict[int, int]:
        """Module-5 parameter -> word of every bias this change writes."""
        fam = self.state.family
        out = {}
        if self.biases is not None:
            old = self.state.current.words(fam)
            out.update({a: w for a, w in self.biases.words(fam).items() if old[a] != w})
        for addr, (c, f) in self.raw.items():
            name = next(n for n, a in BIAS_ADDRESSES[fam].items() if a == addr)
            out[addr] = replace(_raw_template(fam, name), coarse=c, fine=f).word()
        return out

    def settings(self) -> DvsSettings:
        """The settings after the change (the model's estimate)."""
        return self.state.model.settings(self.biases if self.biases is not None else self.state.current)

    def describe(self) -> str:
        """One line: what was asked, what the biases give, which words moved."""
        moved = ", ".join(
            f"{_name(self.state.family, a)} {CoarseFine.parse(w)}" for a, w in sorted(self.words().items())
        )
        if self.filters:
            k, steps = next(iter(self.filters.items()))
            return f"dvs.{k} = {steps * FILTER_STEP_US} µs" + (" (off)" if steps == 0 else "")
        s = self.settings()
        got = {
            "c_on": f"c_on {s.c_on:.4g}",
            "c_off": f"c_off {s.c_off:.4g}",
            "refractory_us": f"refractory {s.refractory_us:.4g} µs",
            "bandwidth_hz": f"bandwidth {s.bandwidth_hz:.4g} Hz",
        }.get(self.key)
        head = f"{'dvs.' if not self.key.startswith('bias.') else ''}{self.key} = {self.value}"
        if got is None and self.biases is not None:
            got = f"c_on {s.c_on:.4g}, c_off {s.c_off:.4g}, refractory {s.refractory_us:.4g} µs, bandwidth {s.bandwidth_hz:.4g} Hz"
        return head + (f": the biases give {got}" if got else "") + (f" ({moved})" if moved else " (no bias moved)")


def _name(family: str, addr: int) -> str:
    return next((n for n, a in BIAS_ADDRESSES[family].items() if a == addr), str(addr))


def _raw_template(family: str, name: str) -> CoarseFine:
    """Flags of a bias outside the six (libcaer's default word for it: N or P type, cascode, enabled)."""
    p_type = name.endswith("BP")
    cascode = family == "DAVIS240" and name in ("APSCASEPC", "DIFFCASBNC")
    enabled = not (family == "DAVIS346" and name == "PADFOLLBN")
    return CoarseFine(0, 0, enabled=enabled, sex_n=not p_type, type_normal=not cascode)
