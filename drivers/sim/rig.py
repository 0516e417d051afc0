"""Simulated cameras: one scene, one event stream, any number of exposure states.

:class:`SimRig` renders the scene at sample times (every ``sample_us``, refined where the light
changes fast), turns consecutive samples into DVS events once, and runs one APS exposure schedule
per camera. It is a :class:`~necviz.drivers.source.Source`: :meth:`SimRig.packets` yields
``(camera, packet)`` pairs in time order, ``camera`` being ``None`` for the shared event batches.
A single simulated camera is a rig of one (``SimRig(scene, ["camera"])``).

Closed loop: ``set_exposure(name, exposure_us, gain)`` records a command at the time of the last
packet delivered (or ``issue_time_us``); it takes effect at the first exposure that starts at
least ``latency_us`` after it was issued. Both the commanded values (``commands(name)``, the last
:data:`COMMAND_HISTORY` of them) and the
applied ones (every :class:`Frame`) are kept.

Ground truth: every frame carries ``frame.truth``, a :class:`~necviz.core.ground_truth.GroundTruth` with
what a camera cannot know — the exposure-averaged irradiance of each pixel the frame was formed
from, the scene's lighting trace (mean ``ln L`` at every rendered sample) from ``2 frame
intervals + latency`` before the exposure to its end, the camera's limits and command latency,
the scene's lighting changes and, where the scene has them, the pedestrian's box and the fiducial
markers' corners at mid-exposure. Attaching it
reads the simulation and changes nothing in it: the frames and events are the same with
``RigOptions(truth=False)``.

Threads: with ``RigOptions(threads=True)`` (the default, :attr:`SimRig.THREADS`) the work that does not depend
on the consumer runs beside it — scene rendering up to :attr:`SimRig.RENDER_AHEAD` sample periods
ahead on one worker thread (:attr:`SimRig.RENDER_CHUNK` periods per job), the DVS steps of each
rendered chunk on a second, and every frame's formation (integration and noise) on a third,
started when its exposure ends, so it overlaps the readout delay. Each worker runs its jobs in
submission order and every camera has its own noise generator, so the packets are exactly those
of ``threads=False``, which does everything on the caller's thread (the reference the tests
compare against). ``samples_rendered`` then also counts samples rendered ahead of a consumer that
stopped early.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from necviz.core.checks import check_number
from necviz.core.control.controller import CameraLimits
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ground_truth import TRACE_STEP, GroundTruth
from necviz.drivers.sim.aps import ApsParams, expose, integrate_samples
from necviz.drivers.sim.dvs import DvsParams, EventSimulator
from necviz.drivers.sim.scene import Scene
from necviz.drivers.source import CameraInfo, CommandRecord, Source

#: commands kept per camera once applied or superseded (``SimRig.commands``); older ones are forgotten
COMMAND_HISTORY = 4096

# at equal times: an exposure ends, then a frame is read out, then the next exposure starts
_END, _FRAME, _START = 0, 1, 2


@dataclass
class _CamState:
    name: str
    exposure_us: float
    gain: float
    rng: np.random.Generator
    pending: list = field(default_factory=list)  # commands not yet old enough to apply (a few at most)
    history: deque = field(default_factory=lambda: deque(maxlen=COMMAND_HISTORY))  # applied or superseded
    seq: int = 0
    frames: int = 0


def _step(dvs: EventSimulator, ls: np.ndarray, ts: int) -> tuple:
    """``dvs.step`` to ``ts``: its events and the events lost at the bus ceiling so far (ON, OFF)."""
    ev = dvs.step(ls, ts)
    return ev, dvs.dropped_on_by_ceiling, dvs.dropped_off_by_ceiling


def _steps(dvs: EventSimulator, samples: list) -> list:
    """:func:`_step` through ``samples`` (``(ln L, t)`` each), in order."""
    return [_step(dvs, ls, ts) for ls, ts in samples]


@dataclass(frozen=True)
class RigOptions:
    """How a :class:`SimRig` samples its scene and delivers the packets (validated here, once).

    Parameters
    ----------
    sample_us : int
        Base period of the scene samples (µs, > 0); events are interpolated in between.
    refine_log : float
        A sample interval over which the mean absolute change of ln L exceeds this (ln, > 0) is
        halved, down to ``min_sample_us`` (ESIM-style adaptive sampling).
    min_sample_us : int
        The shortest sample interval refinement makes (µs, > 0).
    batch_us : int
        Event batches are delivered at least this often (µs, > 0).
    first_start_us : int
        Start of every camera's first exposure (µs, >= 0).
    truth : bool
        Attach :class:`~necviz.core.ground_truth.GroundTruth` to every frame (``frame.truth``).
    threads : bool, optional
        Render, simulate events and form frames on worker threads (``None``: :attr:`SimRig.THREADS`);
        ``False`` runs everything on the consumer's thread. The packets are identical either way.

    Raises
    ------
    ParameterError
        A period that is not a positive whole number of µs, a negative first start, or a
        ``refine_log`` that is not a positive finite number.
    """

    sample_us: int = 2_000
    refine_log: float = 0.12
    min_sample_us: int = 60
    batch_us: int = 1_000
    first_start_us: int = 1_000
    truth: bool = True
    threads: bool | None = None

    def __post_init__(self) -> None:
        for label in ("sample_us", "min_sample_us", "batch_us"):
            v = getattr(self, label)
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise ParameterError(f"{label} must be a positive integer (µs), got {v!r}")
        r = self.refine_log
        if isinstance(r, bool) or not (isinstance(r, (int, float)) and r > 0 and math.isfinite(r)):
            raise ParameterError(f"refine_log must be a positive number, got {r!r}")
        object.__setattr__(self, "refine_log", float(r))
        object.__setattr__(self, "first_start_us", check_number("first_start_us", self.first_start_us, 0, integer=True))
        object.__setattr__(self, "truth", bool(self.truth))
        object.__setattr__(self, "threads", None if self.threads is None else bool(self.threads))


class SimRig(Source):
    """Several simulated cameras sharing one scene and one event stream.

    Parameters
    ----------
    scene : Scene
        The irradiance field.
    cameras : sequence of str or dict
        Camera names, or ``{name: (initial exposure µs, initial gain)}`` (``None``: a mid-range start).
    dvs : DvsParams, optional
        The event model (default: ``DvsParams()``, the simulated DAVIS346).
    aps : ApsParams, optional
        The frame model (default: ``ApsParams()``).
    crf : CameraResponse, optional
        The camera response of every camera (default: the DAVIS346-like curve).
    seed : int
        Seed of the event model and of every camera's frame noise.
    options : RigOptions, optional
        Sampling, batching, first exposure start, ground truth and threads (default: ``RigOptions()``).
    cache : SceneCache, optional
        A :class:`~necviz.drivers.sim.scene_cache.SceneCache`: read the rendered scene and its events
        from it when this stream is there, else write it there (when the whole scene is simulated). The
        packets are identical either way; only the scene's rendering and the event model are skipped.

    Raises
    ------
    ParameterError
        Not a :class:`Scene`, no camera, an initial setting that is not positive (or a gain below 1),
        or ``options`` that is not a :class:`RigOptions`.
    """

    #: default of ``RigOptions.threads``: worker threads for rendering, events and frames
    THREADS = True
    #: scene sample periods rendered ahead of the consumer with threads (bounded memory: one image each)
    RENDER_AHEAD = 8
    #: sample periods per job of the render worker (and per DVS job it passes on): fewer hand-overs between threads
    RENDER_CHUNK = 4

    def __init__(
        self,
        scene: Scene,
        cameras,
        *,
        dvs: DvsParams | None = None,
        aps: ApsParams | None = None,
        crf: CameraResponse | None = None,
        seed: int = 0,
        options: RigOptions | None = None,
        cache=None,
    ):
        if not isinstance(scene, Scene):
            raise ParameterError("SimRig needs a Scene (see necviz.drivers.sim.scenes)")
        if isinstance(cameras, (list, tuple)):
            cameras = {name: None for name in cameras}
        if not cameras:
            raise ParameterError("SimRig needs at least one camera")
        options = RigOptions() if options is None else options
        if not isinstance(options, RigOptions):
            raise ParameterError(f"SimRig takes RigOptions, got {type(options).__name__}")
        self.options = options
        self.scene = scene
        self.sensor = scene.sensor
        self.dvs_params = dvs or DvsParams()
        self.dvs_base = self.dvs_params  # the pixel at libcaer's default biases (set_dvs_biases scales it)
        self.dvs_family = "DAVIS346"
        self._dvs_words: dict[int, int] = {}
        self._dvs_sim: EventSimulator | None = None  # the running event model (None: not started, or cached)
        self._dvs_live = False  # set: the DVS changed while running, so this stream is not the cache's
        self._dvs_from_cache = False  # set while the events are read from the scene cache
        self.aps = aps or ApsParams()
        self.crf = crf or default_davis346()
        self.seed = int(seed)
        self.sample_us, self.refine_log, self.min_sample_us = (
            options.sample_us,
            options.refine_log,
            options.min_sample_us,
        )
        self.batch_us = options.batch_us
        self.first_start_us = options.first_start_us
        self.truth = options.truth
        self.threads = self.THREADS if options.threads is None else options.threads
        self.cache = cache
        self.samples_cached = 0  # scene samples read from the cache instead of rendered
        self.cache_written = False
        # the lighting trace kept for ground truth: (sample time, mean ln L on the TRACE_STEP grid)
        self._trace_t: deque = deque()
        self._trace_l: deque = deque()
        # events lost at the bus ceiling, for ground truth: (DVS step time, cumulative ON, cumulative OFF)
        self._lost: deque = deque()
        self._changes = tuple(scene.changes)
        self._pedestrian = scene.pedestrian_box
        self._markers = scene.marker_truth
        self.cams: dict[str, _CamState] = {}
        for i, (name, init) in enumerate(cameras.items()):
            exp_us, gain = init if init is not None else (self._default_exposure(), 1.0)
            self._check_setting(name, exp_us, gain)
            # SFC64: NumPy's fastest bit generator here (frame noise is ~40 % cheaper than with PCG64)
            rng = np.random.Generator(np.random.SFC64(np.random.SeedSequence([self.seed, 7, i])))
            self.cams[name] = _CamState(name, float(exp_us), float(gain), rng)
        self.now_us = 0
        self.samples_rendered = 0
        self.events_generated = 0

    def _default_exposure(self) -> float:
        """Mid-range start: the exposure that would be right for the scene's first sample."""
        mean_log = float(np.mean(self.scene.log_irradiance(0)))
        t = math.exp(self.crf.goal_log_exposure - mean_log) * 1e6
        return float(min(max(t, self.aps.exposure_min_us), self.aps.exposure_max_us))

    def _check_setting(self, name, exposure_us, gain) -> None:
        for label, v in (("exposure_us", exposure_us), ("gain", gain)):
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float, np.floating, np.integer))
                or not math.isfinite(v)
                or v <= 0
            ):
                raise ParameterError(f"camera {name!r}: {label} must be a positive finite number, got {v!r}")
        if gain < 1.0:
            raise ParameterError(f"camera {name!r}: gain must be >= 1, got {gain}")

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(self.cams)

    # -- commands -------------------------------------------------------------------------------
    def set_exposure(
        self, name: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None:
        """Command camera ``name``; applied at its first exposure starting >= issue time + latency.

        The issue time is the time of the last packet delivered (``issue_time_us`` overrides it).
        """
        if name not in self.cams:
            raise ParameterError(f"no simulated camera named {name!r} (have {', '.join(self.cams)})")
        self._check_setting(name, exposure_us, gain)
        t = self.now_us if issue_time_us is None else int(issue_time_us)
        self.cams[name].pending.append(CommandRecord(t, float(exposure_us), float(gain)))

    # -- DVS biases (issue 29) ----------------------------------------------------------------------
    takes_dvs_biases = True

    @property
    def dvs_pixel(self) -> DvsParams:
        """The simulated pixel at libcaer's default biases (:attr:`dvs_base`)."""
        return self.dvs_base

    def set_dvs_biases(self, words: dict[int, int]) -> None:
        """Write DVS bias words (module-5 parameter -> word, as to a DAVIS346): the event model takes the
        thresholds, refractory period and bandwidth they give (:func:`~necviz.drivers.sim.dvs.params_for_biases`)."""
        from necviz.core.biases import DvsBiases
        from necviz.drivers.sim.dvs import params_for_biases

        merged = {**self._dvs_words, **{int(k): int(v) for k, v in words.items()}}
        params = params_for_biases(self.dvs_base, DvsBiases.from_words(merged, self.dvs_family), self.dvs_family)
        self.set_dvs_params(params)
        self._dvs_words = merged

    def set_dvs_params(self, params: DvsParams) -> None:
        """New event-model parameters (thresholds, refractory period, bandwidth): before :meth:`packets` they are
        the run's; while running they apply from the next DVS step (:meth:`dvs_applied_us` says when).

        Raises :class:`ParameterError` while the events come from the scene cache (they are not simulated)."""
        if self._dvs_from_cache:
            raise ParameterError(
                "this run replays its events from the scene cache, so the DVS cannot change mid-run; "
                "set it at the start (--dvs KEY=VALUE)"
            )
        if self._dvs_sim is None:
            self.dvs_params = params
            return
        self._dvs_sim.retune(params)
        self._dvs_live = True  # this stream is no longer the cache's
        self.dvs_params = params

    def dvs_applied_us(self) -> int | None:
        """Scene time from which the last DVS change holds (``None``: none yet applied while running)."""
        sim = self._dvs_sim
        return None if sim is None or sim._retune is not None else sim.retuned_us

    def set_dvs_filters(self, background_activity_us: float | None, refractory_us: float | None) -> None:
        raise ParameterError("the simulator has no FPGA event filters (a DAVIS camera has: necviz live)")

    def commands(self, name: str) -> list[CommandRecord]:
        """The camera's commands, oldest first: the last :data:`COMMAND_HISTORY` applied or
        superseded ones (``applied_start_us`` set on those that took effect), then those pending."""
        cam = self.cams[name]
        return [*cam.history, *cam.pending]

    def _apply_pending(self, cam: _CamState, start_us: int) -> None:
        """The setting for an exposure starting now: the newest command old enough (latency).

        The chosen command and every one before it leave the pending list (a later exposure can
        only choose a newer one), so the work and memory per exposure stay constant.
        """
        pending = cam.pending
        chosen = None
        for i in range(len(pending) - 1, -1, -1):
            if pending[i].issue_time_us + self.aps.latency_us <= start_us:
                chosen = i
                break
        if chosen is None:
            return
        c = pending[chosen]
        cam.history.extend(pending[:chosen])  # superseded before they could apply
        cam.history.append(replace(c, applied_start_us=int(start_us)))
        del pending[: chosen + 1]
        cam.exposure_us = float(min(max(c.exposure_us, self.aps.exposure_min_us), self.aps.exposure_max_us))
        cam.gain = float(min(max(c.gain, 1.0), self.aps.gain_max))

    # -- simulation -----------------------------------------------------------------------------
    def _sample(self, t0: int, l0: np.ndarray, t1: int, out: list) -> np.ndarray:
        """Render at ``t1``, halving the interval while the *lighting* changes by more than ``refine_log``.

        Lighting change = the mean absolute change of ln L over the sensor. Motion alone does
        not refine: a moving edge changes a few pixels a lot, and the event model interpolates
        each pixel's crossing times linearly between samples anyway.
        """
        l1 = self.scene.log_irradiance(t1)
        self.samples_rendered += 1
        if t1 - t0 >= 2 * self.min_sample_us and float(np.mean(np.abs(l1 - l0))) > self.refine_log:
            tm = (t0 + t1) // 2
            lm = self._sample(t0, l0, tm, out)
            return self._sample(tm, lm, t1, out)
        out.append((t1, l1))
        return l1

    def _render_periods(self, state: list, periods: int, dvs, pool) -> list:
        """The scene samples of the next ``periods`` sample periods (``state = [t_rendered, ln L there]``,
        advanced), one list per period.

        Each sample is ``(t, L, trace value, events)``: ``L = exp(ln L)`` for frame integration, the
        lighting-trace value (``None`` without truth) and the sample's DVS step (:func:`_step`: its
        events and the cumulative counts lost at the ceiling) — with ``pool``,
        ``(future, k)``: the ``k``-th result of one job that steps the simulator through every sample of
        these periods (jobs run in submission order).
        """
        out, steps = [], []
        for _ in range(periods):
            t0, l_prev = state
            target = t0 + self.sample_us
            samples: list = []
            state[1] = self._sample(t0, l_prev, target, samples)
            state[0] = target
            period = []
            for ts, ls in samples:
                trace = float(ls[::TRACE_STEP, ::TRACE_STEP].mean(dtype=np.float64)) if self.truth else None
                if pool is None:
                    ev = _step(dvs, ls, ts)
                else:
                    ev = len(steps)
                    steps.append((ls, ts))
                period.append((ts, np.exp(ls), trace, ev))
            out.append(period)
        if pool is not None:
            job = pool.submit(_steps, dvs, steps)
            out = [[(ts, lin, trace, (job, k)) for ts, lin, trace, k in period] for period in out]
        return out

    def _expose_frame(self, cam: _CamState, times, values, s: int, e: int, gain: float):
        """Exposure ``[s, e]`` of one camera from the scene samples covering it: ``(image, Lbar)``.
        Draws the camera's noise, so a camera's exposures are formed in the order they end."""
        lbar = integrate_samples(times, values, s, e)
        return expose(lbar, e - s, gain, self.crf, self.aps, cam.rng), lbar

    def _form_frame(self, cam: _CamState, formed, s: int, e: int, gain: float) -> Frame:
        """The :class:`Frame` of exposure ``[s, e]`` from its ``(image, Lbar)``."""
        img, lbar = formed
        frame = Frame(img, int(s), int(e), float(gain), cam.seq, self._truth(lbar, s, e) if self.truth else None)
        cam.seq += 1
        return frame

    @property
    def camera_info(self) -> CameraInfo:
        """The simulated cameras: the APS model's limits, latency and frame period, the DVS model's bus ceiling."""
        a = self.aps
        return CameraInfo(
            CameraLimits(a.exposure_min_us, a.exposure_max_us, a.gain_max),
            float(a.latency_us),
            self.dvs_params.max_event_rate,
            float(a.frame_interval_us),
        )

    @property
    def truth_lookback_us(self) -> int:
        """How far before an exposure start the lighting trace attached to a frame reaches."""
        return 2 * self.aps.frame_interval_us + self.aps.latency_us

    def _trace(self, t_us: int, log_l: np.ndarray | None = None, value: float | None = None) -> None:
        if self.truth:
            self._trace_t.append(int(t_us))
            if value is None:
                value = float(log_l[::TRACE_STEP, ::TRACE_STEP].mean(dtype=np.float64))
            self._trace_l.append(value)

    def _truth(self, lbar: np.ndarray, s: int, e: int) -> GroundTruth:
        """The frame's ground truth (reads the simulation, changes nothing)."""
        tt = np.fromiter(self._trace_t, np.int64, len(self._trace_t))
        ll = np.fromiter(self._trace_l, np.float64, len(self._trace_l))
        i0 = max(int(np.searchsorted(tt, s - self.truth_lookback_us, side="right")) - 1, 0)
        i1 = int(np.searchsorted(tt, e, side="left")) + 1
        box = None
        if self._pedestrian is not None:
            box = self._pedestrian((s + e) / 2)
        a = self.aps
        lost = np.array([x for x in self._lost if x[0] <= e] or [(0, 0, 0)], np.int64)
        return GroundTruth(
            lbar,
            self.crf,
            tt[i0:i1],
            ll[i0:i1],
            float(a.latency_us),
            float(a.exposure_min_us),
            float(a.exposure_max_us),
            float(a.gain_max),
            float(a.readout_us),
            self._changes,
            box,
            markers=None if self._markers is None else self._markers((s + e) / 2),
            lost_t_us=lost[:, 0],
            lost_on=lost[:, 1],
            lost_off=lost[:, 2],
            event_thresholds=(float(self.dvs_params.c_on), float(self.dvs_params.c_off)),
        )

    def _open_cache(self, last_target: int):
        """``(reader, writer)`` of the scene cache for this stream (either or both ``None``)."""
        if self.cache is None:
            return None, None
        key = self.cache.key(self)
        if key is None:
            return None, None
        reader = self.cache.open(key, self.sensor.shape)
        if reader is not None:
            return reader, None
        expected = int(1.2 * (last_target // self.sample_us + 1))  # with a margin for refined samples
        return None, self.cache.writer(key, self.sensor.shape, expected)

    def packets(self):
        """Yield ``(camera name or None, packet)`` in time order until the scene ends."""
        end = self.scene.duration_us
        last_target = -(-(end + 2 * self.sample_us) // self.sample_us) * self.sample_us  # as the serial loop
        reader, writer = self._open_cache(last_target)
        self._trace_t.clear()
        self._trace_l.clear()
        self._lost.clear()
        self._lost.append((0, 0, 0))
        dvs = None
        self._dvs_from_cache = reader is not None
        if reader is not None:  # the scene and its events from the cache: nothing to render or simulate
            lin0, trace0 = reader.first()
            self.samples_cached += 1
            self._trace(0, value=trace0)
            l_prev = None
        else:
            dvs = EventSimulator(self.sensor, self.dvs_params, seed=self.seed)
            self._dvs_sim = dvs
            l_prev = self.scene.log_irradiance(0)
            self.samples_rendered += 1
            dvs.reset(l_prev, 0)
            self._trace(0, l_prev)
            lin0 = np.exp(l_prev)
            if writer is not None:
                writer.sample(0, lin0, self._trace_l[-1] if self.truth else None)
                writer.events(np.zeros(0, EVENT_DTYPE))
        buf_t: deque = deque([0])
        buf_l: deque = deque([lin0])
        held = np.zeros(0, EVENT_DTYPE)
        pending: deque = deque()
        t_rendered = t_gathered = 0
        render_state = [0, l_prev]
        # with threads: [render worker, DVS worker, frame worker]; each runs its jobs in submission order
        pools = (
            [ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"necviz-{n}") for n in ("render", "dvs", "aps")]
            if self.threads
            else []
        )
        complete = False
        renders: deque = deque()  # futures of the periods rendered ahead (threads), a chunk of periods each
        ready: deque = deque()  # rendered periods not yet taken
        t_submitted = 0
        forming: dict = {}  # (camera index, exposure start) -> future of (image, Lbar) (threads)
        heap: list = []
        for i, name in enumerate(self.cams):
            heapq.heappush(heap, (self.first_start_us, _START, i, name, None))
        try:
            t0 = 0
            while t0 < end:
                t1 = min(t0 + self.batch_us, end)
                # Scene samples run on their own grid, rendered up to two periods past the batch (with
                # threads, RENDER_AHEAD periods ahead on the render worker, whose samples go on to the DVS
                # worker). Events past t1 wait for the next batch.
                while t_rendered < t1 + 2 * self.sample_us:
                    if reader is not None:
                        samples = reader.period()
                        self.samples_cached += len(samples)
                    elif pools:
                        ahead = len(ready) + sum(f[1] for f in renders)
                        while t_submitted < last_target and ahead < self.RENDER_AHEAD:
                            k = min(self.RENDER_CHUNK, (last_target - t_submitted) // self.sample_us)
                            renders.append((pools[0].submit(self._render_periods, render_state, k, dvs, pools[1]), k))
                            t_submitted += k * self.sample_us
                            ahead += k
                        if not ready:
                            ready.extend(renders.popleft()[0].result())
                        samples = ready.popleft()
                    else:
                        samples = self._render_periods(render_state, 1, dvs, None)[0]
                    for ts, lin, trace, ev in samples:
                        self._trace(ts, value=trace)
                        pending.append((ts, ev))
                        buf_t.append(ts)
                        buf_l.append(lin)
                        if writer is not None:
                            writer.sample(ts, lin, trace)
                    t_rendered += self.sample_us
                chunks = [held] if held.size else []
                while t_gathered < t1:
                    t_gathered, ev = pending.popleft()
                    if pools and reader is None:
                        ev = ev[0].result()[ev[1]]
                    ev, lost_on, lost_off = ev
                    if self.truth:
                        self._lost.append((t_gathered, lost_on, lost_off))
                    if writer is not None:
                        writer.events(ev, lost_on, lost_off)
                    if ev.size:
                        chunks.append(ev)
                events = np.concatenate(chunks) if len(chunks) > 1 else (chunks[0] if chunks else held)
                times = np.ascontiguousarray(events["t"])  # searched once per camera item: one copy, not one each
                split = int(times.searchsorted(t1, side="left"))
                events, held = events[:split], events[split:]
                times = times[:split]
                self.events_generated += events.size
                pos = 0
                # camera items due before t1 (an item may schedule another within the same batch)
                while heap and heap[0][0] < t1:
                    t_item, kind, ci, name, data = heapq.heappop(heap)
                    cut = int(times.searchsorted(t_item, side="left"))
                    if cut > pos:
                        self.now_us = int(times[cut - 1])
                        yield None, EventBatch(events[pos:cut])
                        pos = cut
                    cam = self.cams[name]
                    self.now_us = max(self.now_us, int(t_item))
                    if kind == _START:
                        self._apply_pending(cam, t_item)
                        e = t_item + max(1, int(round(cam.exposure_us)))
                        heapq.heappush(heap, (e, _END, ci, name, (t_item, cam.exposure_us, cam.gain)))
                        yield name, ExposureMarker(int(t_item), "start")
                    elif kind == _END:
                        s, exp_us, gain = data
                        heapq.heappush(heap, (t_item + self.aps.readout_us, _FRAME, ci, name, (s, t_item, gain)))
                        heapq.heappush(heap, (s + self.aps.frame_interval_us, _START, ci, name, None))
                        if pools:  # the samples covering [s, e] are all here: form it during the readout
                            forming[ci, s] = pools[2].submit(
                                self._expose_frame,
                                cam,
                                np.asarray(buf_t, dtype=np.float64),
                                list(buf_l),
                                s,
                                t_item,
                                gain,
                            )
                        yield name, ExposureMarker(int(t_item), "end")
                    else:
                        s, e, gain = data
                        if pools:
                            formed = forming.pop((ci, s)).result()
                        else:
                            formed = self._expose_frame(
                                cam, np.asarray(buf_t, dtype=np.float64), list(buf_l), s, e, gain
                            )
                        frame = self._form_frame(cam, formed, s, e, gain)
                        cam.frames += 1
                        yield name, frame
                if pos < events.size:
                    self.now_us = int(times[-1])
                    yield None, EventBatch(events[pos:])
                self.now_us = max(self.now_us, t1 - 1)
                # keep samples back to the oldest exposure still to be integrated
                oldest = min([h[4][0] for h in heap if h[1] in (_END, _FRAME)] + [t1])
                while len(buf_t) > 2 and buf_t[1] <= oldest:
                    buf_t.popleft()
                    buf_l.popleft()
                keep = oldest - self.truth_lookback_us  # the trace reaches a look-back further
                while len(self._trace_t) > 2 and self._trace_t[1] <= keep:
                    self._trace_t.popleft()
                    self._trace_l.popleft()
                while len(self._lost) > 2 and self._lost[1][0] <= keep:
                    self._lost.popleft()
                t0 = t1
            complete = True
        finally:
            if writer is not None:
                # the samples rendered ahead of the end: their events too (a replay reads them); a stream whose DVS
                # changed mid-run is not the one the cache's key describes
                if complete and not self._dvs_live:
                    for _, ev in pending:
                        writer.events(*(ev[0].result()[ev[1]] if pools else ev))
                    self.cache_written = writer.commit(self.sample_us)
                else:
                    writer.abort()
            for pool in pools:  # the render worker first: it feeds the DVS worker
                pool.shutdown(wait=True, cancel_futures=True)
            self._dvs_sim = None
            self._dvs_from_cache = False

    def warm_up(self) -> None:
        """Compile or load the simulator's kernels (events, frame formation) before the run: a throwaway rig
        on the same scene and models simulates until its first frame (a few ms of scene time, no threads).
        This rig's state, random streams included, is untouched."""
        dvs = self.dvs_params
        if dvs.shot_noise_hz > 0:  # enough shot noise that its kernel runs within the few ms simulated
            dvs = dvs.replace(shot_noise_hz=max(dvs.shot_noise_hz, 1e3))
        mini = SimRig(
            self.scene,
            {"warm-up": (self.aps.exposure_min_us, 1.0)},
            dvs=dvs,
            aps=self.aps,
            crf=self.crf,
            seed=self.seed,
            options=replace(self.options, threads=False),
        )
        gen = mini.packets()
        try:
            for _, p in gen:
                if isinstance(p, Frame):
                    break
        finally:
            gen.close()

    def close(self) -> None:
        """Nothing to release: the simulation ends with its generator."""
