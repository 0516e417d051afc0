"""The DVS controls of a running pipeline: biases written to its camera, P-TEDI following them (issue 29).

``dvs.KEY = VALUE`` (tuning prompt, tune file) and ``--dvs KEY=VALUE`` (``live``, ``demo``) go to
:meth:`DvsControls.set`. Keys: :data:`~necviz.core.biases.CONTROLS` (``c_on``, ``c_off``, ``refractory_us``,
``bandwidth_hz``, the FPGA's ``ba_filter_us`` and ``refractory_filter_us``) and ``bias.NAME`` (a raw
``COARSE/FINE``). The bias model (:mod:`necviz.core.biases`) turns a request into bias words; the source writes
them (``set_dvs_biases``: the live driver through the request that wrote libcaer's defaults, the emulated camera
and the simulator into their event model). A request is checked whole before anything is written: refused, it
changes nothing.

P-TEDI follows: each lane's estimator gets ``c = c_profile * model ratio`` (``c_profile``: its thresholds
before the first change, i.e. the camera profile's, calibrated at libcaer's default biases) through
``PeripheralEstimator.set_contrast_thresholds``, at the event batch where the change took effect in the stream
(the source's ``dvs_applied_us``: exact for the simulator and the emulated camera; for a real camera the time
of the last packet delivered when the biases were written). A request is interpreted against the first lane's
profile: ``dvs.c_on = 0.15`` asks the camera for 0.15 as that profile measures it.
"""

from __future__ import annotations

from collections import deque

from necviz.core.biases import FILTER_STEP_US, BiasModel, DvsBiases, DvsSettings, DvsState, physical_settings
from necviz.core.errors import ParameterError

#: the thresholds P-TEDI accepts (``TediParams``, ln)
PTEDI_MIN, PTEDI_MAX = 0.005, 5.0
#: the prefixes that mark a DVS control at the tuning prompt (``dvs.c_on``, ``bias.DiffBn``)
PREFIXES = ("dvs", "bias")


def parse_assignment(text: str, where: str = "--dvs") -> tuple[str, str]:
    """``"c_on=0.15"`` (or ``"dvs.c_on=0.15"``, ``"bias.DiffBn=4/39"``) -> ``("c_on", "0.15")``; one-line error."""
    key, sep, value = str(text).partition("=")
    key, value = key.strip(), value.strip()
    if not sep or not key or not value:
        raise ParameterError(f"{where} takes KEY=VALUE (e.g. c_on=0.2, bias.DiffBn=4/39), got {text!r}")
    if key.startswith("dvs."):
        key = key[4:]
    return key, value


def check_assignments(items) -> tuple[tuple[str, str], ...]:
    """Every ``--dvs`` item parsed and checked against the model (before anything opens); refused in one line."""
    out = []
    states = (DvsState(), DvsState(BiasModel("DAVIS240")))  # the camera is not known yet: either chip's names
    for item in items or ():
        key, value = parse_assignment(item)
        try:
            states[0].request(key, value, reach=False)  # nonsense is refused here, reachability when applied
        except ParameterError as first:
            if not key.startswith("bias."):
                raise
            try:
                states[1].request(key, value, reach=False)
            except ParameterError:
                raise first from None
        out.append((key, value))
    return tuple(out)


def _estimator(lane):
    """A pipeline lane's P-TEDI estimator (``Lane.estimator``: a pipeline gives every lane one)."""
    est = lane.estimator
    assert est is not None
    return est


class DvsControls:
    """The DVS settings of one pipeline's source and the lanes' P-TEDI thresholds that follow them."""

    def __init__(self, source, lanes: dict):
        self.source = source
        self.lanes = lanes
        self.state: DvsState | None = None
        self._base: dict[str, tuple[float, float]] = {}  # lane -> P-TEDI (c_on, c_off) at libcaer's default biases
        self._pending: dict[str, tuple[float, float]] | None = None  # thresholds waiting for the change to show
        self.followed: dict[str, tuple[float, float]] = {}  # lane -> the thresholds P-TEDI uses since a change
        self.followed_from_us: int | None = None  # stream time the last change took effect
        self.ratio: dict | None = None  # the model's threshold ratios (to the default biases) of the last change
        self._schedule: deque = deque()  # a replayed recording's changes: (from_us, ratio, recorded dvs settings)
        self.replayed_dvs: dict | None = None  # the recorded settings of the change last followed in a replay
        self.history: list[dict] = []  # every change: time, key, value, settings

    @property
    def available(self) -> bool:
        return self.source.takes_dvs_biases

    def _ensure_state(self) -> DvsState:
        if self.state is None:
            if not self.available:
                raise ParameterError(
                    f"{type(self.source).__name__} takes no DVS bias changes (the simulator, the emulated camera, "
                    "necviz's USB driver and --device dv do; a recording is replayed as it was)"
                )
            first = _estimator(next(iter(self.lanes.values()))).params
            family = self.source.dvs_family
            # refractory period and bandwidth at the default biases: the simulator's own pixel where there is one
            # (the simulator, the emulated camera), else the model's estimate (jAER's constants)
            base = self.source.dvs_pixel
            phys = physical_settings(DvsBiases.defaults(family))
            ref = DvsSettings(
                first.c_on,
                first.c_off,
                base.refractory_us if base is not None else phys.refractory_us,
                (base.cutoff_hz if base is not None else None) or phys.bandwidth_hz,
            )
            self.state = DvsState(BiasModel(family, ref))
            self._capture_base()
        return self.state

    def _capture_base(self) -> None:
        if not self._base:
            self._base = {n: (_estimator(ln).params.c_on, _estimator(ln).params.c_off) for n, ln in self.lanes.items()}

    def set(self, key: str, value, t_us: int | None, started: bool) -> tuple[str, dict]:
        """Carry out one control: ``(message, data)`` for the tuning log and the recordings.

        ``started``: the stream has delivered packets (else P-TEDI takes the new thresholds at once)."""
        state = self._ensure_state()
        change = state.request(key, value)
        if change.filters:
            steps = {
                "ba_filter_us": state.ba_filter_steps,
                "refractory_filter_us": state.refractory_filter_steps,
                **change.filters,
            }
            ba, refr = (steps[k] * FILTER_STEP_US or None for k in ("ba_filter_us", "refractory_filter_us"))
            self.source.set_dvs_filters(ba, refr)
        words = change.words()
        msg = change.describe()  # before it applies: which words move
        if change.biases is not None:  # every lane's P-TEDI must be able to take its new thresholds: else nothing moves
            r = state.model.ratios(change.biases)
            for name, (b_on, b_off) in self._base.items():
                if not (PTEDI_MIN <= b_on * r.c_on <= PTEDI_MAX and PTEDI_MIN <= b_off * r.c_off <= PTEDI_MAX):
                    raise ParameterError(
                        f"{msg}: lane {name}'s P-TEDI would take c_on={b_on * r.c_on:.3g}, c_off={b_off * r.c_off:.3g}, "
                        f"outside {PTEDI_MIN:g}..{PTEDI_MAX:g} ln; nothing was written"
                    )
        if words:
            self.source.set_dvs_biases(words)
        s = change.settings()
        follow = {}
        before = state.model.ratios(state.current)
        state.apply(change)
        after = state.model.ratios(state.current)
        if (after.c_on, after.c_off) != (before.c_on, before.c_off):  # the thresholds moved: P-TEDI follows
            r = after
            follow = {n: (b_on * r.c_on, b_off * r.c_off) for n, (b_on, b_off) in self._base.items()}
            self.ratio = {"c_on": r.c_on, "c_off": r.c_off}
            if not started:
                self._follow(follow)
            else:
                self._pending = follow
            msg += "; P-TEDI follows" + ("" if not started else " where the change shows in the stream")
        data = {
            "dvs": {
                "key": change.key,
                "value": str(change.value),
                "words": {str(a): int(w) for a, w in words.items()},
                **s.as_dict(),
                "ba_filter_us": state.ba_filter_steps * FILTER_STEP_US,
                "refractory_filter_us": state.refractory_filter_steps * FILTER_STEP_US,
                "ptedi": {n: {"c_on": c[0], "c_off": c[1]} for n, c in follow.items()},  # what P-TEDI takes
                **({"ratio": self.ratio} if follow else {}),  # c / c at the default biases (a replay scales by it)
            }
        }
        if follow and not started:  # taken at once (else noted when the change shows in the stream)
            data["ptedi"] = data["dvs"]["ptedi"]
        self.history.append({"t_us": t_us, **data["dvs"]})
        return msg, data

    @property
    def scheduled(self) -> tuple[tuple[int, float, float], ...]:
        """A replayed recording's bias changes P-TEDI has still to follow, in time order: ``(from_us, ratio c_on,
        ratio c_off)`` each (the ratios to the default biases; :meth:`follow_recording` fills it)."""
        return tuple((t, r_on, r_off) for t, r_on, r_off, _ in self._schedule)

    @property
    def pending(self) -> bool:
        return self._pending is not None or bool(self._schedule)

    def follow_recording(self, annotations) -> int:
        """A replayed native recording: P-TEDI takes each recorded bias change at the time it took effect in the
        recorded stream, its thresholds scaled from this run's by the recorded model ratio (so a replay with
        another profile follows as the camera did). Returns how many changes are scheduled."""
        sched, ratio, dvs = [], None, None
        for t, note in sorted(annotations or (), key=lambda a: a[0]):
            if not isinstance(note, dict):
                continue
            if isinstance(note.get("dvs"), dict):
                dvs = note["dvs"]
                ratio = dvs.get("ratio", ratio)
            ptedi = note.get("ptedi")
            r = note.get("ratio", ratio)
            if isinstance(ptedi, dict) and isinstance(r, dict):
                starts = [v["from_us"] for v in ptedi.values() if isinstance(v, dict) and "from_us" in v]
                sched.append((int(starts[0] if starts else t), float(r["c_on"]), float(r["c_off"]), dvs))
        self._schedule = deque(sched)
        if sched:
            self._capture_base()
        return len(sched)

    def follow_if_applied(self, last_event_us: int) -> int | None:
        """Before a batch ending at ``last_event_us``: if the change shows in it, P-TEDI takes the thresholds
        (returns the time the change took effect; ``None``: not yet)."""
        if self._schedule:  # a replay: the recorded changes, in time order
            if last_event_us < self._schedule[0][0]:
                return None
            while self._schedule and self._schedule[0][0] <= last_event_us:
                t, r_on, r_off, self.replayed_dvs = self._schedule.popleft()
            self.ratio = {"c_on": r_on, "c_off": r_off}
            self._follow({n: (b_on * r_on, b_off * r_off) for n, (b_on, b_off) in self._base.items()})
            self.followed_from_us = int(t)
            return t
        t = self.source.dvs_applied_us()
        if t is None or last_event_us < t:
            return None
        self._follow(self._pending)
        self.followed_from_us = int(t)
        return t

    def _follow(self, follow: dict) -> None:
        self._pending = None
        for name, (c_on, c_off) in follow.items():
            _estimator(self.lanes[name]).set_contrast_thresholds(c_on, c_off)
            self.followed[name] = (c_on, c_off)

    def summary(self) -> dict:
        """Per lane, the thresholds P-TEDI used at the end (``ptedi: {c_on, c_off}``)."""
        return {
            n: {"c_on": float(_estimator(ln).params.c_on), "c_off": float(_estimator(ln).params.c_off)}
            for n, ln in self.lanes.items()
        }
