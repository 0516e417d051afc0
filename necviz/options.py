"""Option objects for the library calls behind every command (:mod:`necviz.app`).

A script or notebook builds one of these and calls a function (``necviz.run_demo(DemoOptions(...),
ViewerOptions(save="demo.rrd"))``); the command line only maps its flags onto them. Every object
is frozen, keyword-only beyond its subject, and checks its values when it is made: a value is refused
with a one-line :class:`~necviz.core.errors.OptionError` (a :class:`~necviz.core.errors.ParameterError`)
naming the field, ``ClipOptions.before_s = -1 is out of range [0, 600]``; the command line shows the
flag instead (:data:`necviz.flags.FIELD_FLAGS`). Files are checked when a run starts, before anything
is opened.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import KW_ONLY, dataclass, field

import necviz.tuned  # noqa: F401 - registers the tuned controllers (navid-tuned, ...) with CONTROLLERS
from necviz.core.checks import check_number
from necviz.core.control import CONTROLLERS
from necviz.core.errors import OptionError, ParameterError
from necviz.flags import (  # noqa: F401 - re-exported
    NUMBER_FLAGS,
    NumberRule,
    check_field,
    check_flag,
    number,
    parse_memory_limit,
)
from necviz.names import (  # noqa: F401 - re-exported
    BASELINES,
    COMPARE_CONTROLLERS,
    DEFAULT_CONTROLLERS,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    LAYOUT_NAMES,
)


def controller_kind(name: str) -> str:
    """The registered controller behind a lane name: ``"nec@median"`` -> ``"nec"`` (a labelled variant)."""
    return str(name).split("@", 1)[0]


def parse_controllers(text, field: str = "controllers") -> tuple[str, ...]:
    """``"nec,navid"`` (or a sequence of names) -> checked names, each registered and given once
    (refused with an :class:`OptionError` naming ``field``).

    A name may carry a label, ``KIND@LABEL`` (``nec@median``), to run several variants of one
    controller side by side (each configured with ``--param nec@median.metering=median``).
    """
    names = [n.strip() for n in text.split(",") if n.strip()] if isinstance(text, str) else [str(n) for n in text]
    unknown = [
        n
        for n in names
        if controller_kind(n) not in CONTROLLERS
        or ("@" in n and not n.split("@", 1)[1].replace("-", "_").isidentifier())
    ]
    if not names or unknown:
        raise OptionError(
            field,
            f"{field}: unknown controller(s) {', '.join(unknown) or '(none given)'}; "
            f"available: {', '.join(sorted(CONTROLLERS))} (a variant: KIND@LABEL)",
        )
    if len(set(names)) != len(names):
        raise OptionError(field, f"each controller may appear once in {field}")
    return tuple(names)


def check_param_lanes(controller_params: dict | None, controllers, field: str = "controller_params") -> None:
    """Every controller that parameters are given for runs (``--param NAME.KEY=VALUE``, a run spec).

    Raises
    ------
    ParameterError
        Parameters for a controller that is not among ``controllers``.
    """
    unknown = set(controller_params or {}) - set(controllers)
    if unknown:
        raise OptionError(
            field,
            f"{field} names {', '.join(sorted(unknown))}, which is not among the controllers ({', '.join(controllers)})",
        )


def parse_speed(text, field: str = "speed") -> float | None:
    """``max`` (as fast as possible) -> None; ``1`` / ``x1`` real time; ``x4`` or ``4`` four times.

    Zero, negative, NaN and infinite factors are refused (``0`` is no speed: ``max`` is), with an
    :class:`OptionError` naming ``field``."""
    if text is None or str(text).strip().lower() in ("max", "fast"):
        return None
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        v = float(text)
    else:
        try:
            v = float(str(text).strip().lower().removeprefix("x"))
        except ValueError:
            raise OptionError(field, f"{field} must be 'max', a factor like 1 or x4, got {text!r}") from None
    r = NUMBER_FLAGS["--speed"]
    assert r.lo is not None and r.hi is not None  # the table bounds --speed at both ends
    if not (math.isfinite(v) and r.lo <= v <= r.hi):
        raise OptionError(
            field, f"{field} must be 'max' (as fast as possible) or a factor between x0.001 and x10000, got {text!r}"
        )
    return v


def parse_setting(text: str, flag: str = "--set", dotted: bool = False) -> tuple[str, object]:
    """``key=value`` (``--set``): the value read as TOML (``90``, ``[1.0, 2.5]``, ``"x"``), else as text.

    ``dotted`` accepts ``name.key`` (``--param nec.goal=110``, ``--sim dvs.c_on=0.3``).
    """
    key, sep, value = str(text).partition("=")
    key = key.strip()
    ok = re.fullmatch(r"[A-Za-z_][\w-]*(@[\w-]+)?\.[A-Za-z_]\w*", key) is not None if dotted else key.isidentifier()
    if not sep or not ok:
        raise ParameterError(f"{flag} expects {'NAME.KEY' if dotted else 'KEY'}=VALUE, got {text!r}")
    try:
        return key, tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return key, value.strip()


def parse_params(items, flag: str = "--param") -> dict:
    """``["nec.goal=110", "navid.target_msv=3"]`` -> ``{"nec": {"goal": 110}, "navid": {"target_msv": 3}}``."""
    out: dict = {}
    for text in items or ():
        key, value = parse_setting(text, flag, dotted=True)
        name, _, param = key.partition(".")
        if not param:
            raise ParameterError(f"{flag} expects NAME.KEY=VALUE, got {text!r}")
        out.setdefault(name, {})[param] = value
    return out


def _scene_inputs(scene: SceneOptions, tune: TuneOptions | None) -> list:
    """The files a scene and live tuning read: a scenario file, a tuning file."""
    return [scene.scenario if scene.is_file else None, tune.file if tune is not None else None]


@dataclass(frozen=True)
class SceneOptions:
    """A simulated scene: a preset name or a TOML scenario file, a seed, a duration, overrides.

    Parameters
    ----------
    scenario : str
        A preset (``tunnel_exit``, ``indoor_outdoor``, ``flicker``, ``static_lab``, ``handheld_scan``)
        or the path of a TOML scenario file.
    seed : int, optional
        The scene's and the sensor noise's seed (``None``: the file's, or 0).
    duration_s : float, optional
        Simulated seconds (``None``: the file's, or the preset's own), at most 600.
    params : dict
        Preset parameters overriding the defaults (``--set key=value``).

    Raises
    ------
    ParameterError
        An unknown preset, an unreadable file, a seed or duration out of range.
    """

    scenario: str = "tunnel_exit"
    _: KW_ONLY
    seed: int | None = None
    duration_s: float | None = None
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        from necviz.drivers.sim.scenes import SCENARIOS

        object.__setattr__(self, "scenario", str(self.scenario))
        if self.scenario not in SCENARIOS and not self.is_file:
            raise OptionError(
                "SceneOptions.scenario",
                f"SceneOptions.scenario: {self.scenario!r} is neither a preset ({', '.join(sorted(SCENARIOS))}) "
                "nor a .toml scenario file",
            )
        if self.seed is not None:
            object.__setattr__(self, "seed", check_field("SceneOptions.seed", self.seed))
        if self.duration_s is not None:
            object.__setattr__(self, "duration_s", check_field("SceneOptions.duration_s", self.duration_s))
        object.__setattr__(self, "params", dict(self.params))

    @property
    def is_file(self) -> bool:
        return self.scenario.endswith(".toml") or os.sep in self.scenario

    def spec(self) -> dict:
        """``{name, seed, duration_us, sensor, params}``: the file's (read and checked) or the preset's."""
        if self.is_file:
            from necviz.drivers.sim.scenes import load_scenario_spec

            return load_scenario_spec(self.scenario)
        return {
            "name": self.scenario,
            "seed": None,
            "duration_us": None,
            "sensor": None,
            "params": {},
            "source": self.scenario,
        }

    @property
    def name(self) -> str:
        return self.spec()["name"] if self.is_file else self.scenario

    @property
    def resolved_seed(self) -> int:
        if self.seed is not None:
            return self.seed
        seed = self.spec()["seed"]
        return 0 if seed is None else int(seed)

    def build(self):
        """The :class:`~necviz.drivers.sim.scene.Scene` these options describe."""
        from necviz.drivers.sim.scenes import make_scenario

        spec = self.spec()
        kw = {"sensor": spec["sensor"]} if spec["sensor"] is not None else {}
        duration_us = int(round(self.duration_s * 1e6)) if self.duration_s is not None else spec["duration_us"]
        try:
            return make_scenario(
                spec["name"],
                duration_us=duration_us,
                seed=self.resolved_seed,
                **kw,
                **{**spec["params"], **self.params},
            )
        except ParameterError as e:
            raise ParameterError(f"{self.scenario}: {e}" if self.is_file else str(e)) from None


@dataclass(frozen=True)
class ViewerOptions:
    """Where the Rerun data goes (as the flags of Rerun's own examples); combine freely.

    With nothing set: a native viewer when a display exists, else a file
    ``necviz-<command>-<time>.rrd``.

    Parameters
    ----------
    spawn : bool
        A native Rerun viewer.
    serve : bool
        Serve the web viewer (``web_port``) and its data (``grpc_port``) on ``bind``.
    connect : str, optional
        Stream to a running viewer at this URL.
    save : path, optional
        Write the recording to this ``.rrd`` file (an existing one only with ``force``; never an input).
    force : bool
        Let ``save`` replace an existing file.
    layout : str, optional
        Override the command's layout (``live``, ``inspect``, ``compare``).
    memory_limit : str
        The viewer's or server's memory limit (``1GB``, ``75%``).
    bind : str
        The address ``serve`` listens on (127.0.0.1 unless the user asks otherwise).
    grpc_port, web_port : int
        The ports of ``serve`` (checked free before anything starts).
    notebook : bool
        Show the viewer inline in the Jupyter cell that runs the command (``rerun-notebook``, the
        optional extra ``notebook``); not combined with the others.

    Raises
    ------
    ParameterError
        A bad port, memory limit or layout, or ``notebook`` combined with another target.
    """

    _: KW_ONLY
    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    save: str | os.PathLike | None = None
    force: bool = False
    layout: str | None = None
    memory_limit: str = "1GB"
    bind: str = "127.0.0.1"
    grpc_port: int = DEFAULT_GRPC_PORT
    web_port: int = DEFAULT_WEB_PORT
    notebook: bool = False

    def __post_init__(self):
        if self.notebook and (self.spawn or self.serve or self.connect or self.save):
            raise OptionError(
                "ViewerOptions.notebook",
                "ViewerOptions.notebook=True shows the viewer in the notebook; do not combine it with spawn, serve, "
                "connect or save",
            )
        if self.layout is not None and self.layout not in LAYOUT_NAMES:
            raise OptionError(
                "ViewerOptions.layout",
                f"ViewerOptions.layout: unknown layout {self.layout!r}; available: {', '.join(LAYOUT_NAMES)}",
            )
        object.__setattr__(self, "grpc_port", check_field("ViewerOptions.grpc_port", self.grpc_port))
        object.__setattr__(self, "web_port", check_field("ViewerOptions.web_port", self.web_port))
        try:
            object.__setattr__(
                self, "memory_limit", parse_memory_limit(self.memory_limit, "ViewerOptions.memory_limit")
            )
        except ParameterError as e:
            raise OptionError("ViewerOptions.memory_limit", str(e)) from None
        if self.serve and self.grpc_port == self.web_port:
            raise OptionError(
                "ViewerOptions.web_port",
                f"ViewerOptions.grpc_port and ViewerOptions.web_port are both {self.grpc_port}; they must differ",
            )

    @property
    def watched(self) -> bool:
        return bool(self.spawn or self.serve or self.connect or self.notebook)


@dataclass(frozen=True)
class ShowOptions:
    """How a dashboard run paces and draws (shared by demo, replay and live).

    Parameters
    ----------
    speed : "auto", "max", float or "xN"
        ``auto``: real time when a viewer watches, as fast as possible into a file; ``1`` real time,
        ``x4`` four times faster, ``max`` as fast as possible.
    event_window_ms : float
        The window of each event image (ms).
    event_points : int
        Also log up to this many raw events per window as points.
    image_rate_hz : float, optional
        Log at most this many frames per lane, and event images, per second of sensor time (the
        scalar series stay whole): a lighter ``--save`` for long runs. ``None``: every one.

    Raises
    ------
    ParameterError
        A speed of zero or below, a window or count out of range.
    """

    speed: object = "auto"  # "auto": real time when a viewer watches, as fast as possible into a file
    _: KW_ONLY
    event_window_ms: float = 33.3
    event_points: int = 0
    image_rate_hz: float | None = None

    def __post_init__(self):
        if self.speed != "auto":
            object.__setattr__(self, "speed", parse_speed(self.speed, "ShowOptions.speed"))
        object.__setattr__(self, "event_window_ms", check_field("ShowOptions.event_window_ms", self.event_window_ms))
        object.__setattr__(self, "event_points", check_field("ShowOptions.event_points", self.event_points))
        if self.image_rate_hz is not None:
            object.__setattr__(self, "image_rate_hz", check_field("ShowOptions.image_rate_hz", self.image_rate_hz))


@dataclass(frozen=True)
class TuneOptions:
    """Live tuning: a prompt on the terminal and/or a watched file.

    Parameters
    ----------
    prompt : bool
        Read tuning commands at a ``tune>`` prompt when the terminal is interactive.
    file : path, optional
        Watch this file: every changed ``key = value`` line is applied when it is saved.
    dvs : tuple of (key, value)
        DVS controls set before the first packet (``--dvs KEY=VALUE``; :mod:`necviz.dvs_controls`).
    """

    _: KW_ONLY
    prompt: bool = True
    file: str | os.PathLike | None = None
    dvs: tuple = ()

    def __post_init__(self):
        from necviz.dvs_controls import check_assignments

        try:  # nonsense is refused here; whether the camera can reach a value, when it is applied
            check_assignments(f"{k}={v}" for k, v in self.dvs)
        except (ParameterError, TypeError, ValueError) as e:
            raise OptionError("TuneOptions.dvs", f"TuneOptions.dvs: {e}") from None


@dataclass(frozen=True)
class ClipOptions:
    """The flight recorder (``--clips DIR``): a clip around every saturated frame and every ``mark``.

    See :mod:`necviz.dashboard.flight_recorder`.

    Parameters
    ----------
    folder : path
        The folder for the clips (created, parents too, when missing).
    before_s, after_s : float
        Seconds kept before a failure and recorded after it (each at most 600).
    memory_mb : float
        The recorder's whole memory budget (MB), its clip writer included; the oldest data is dropped
        beyond it, and counted.

    Raises
    ------
    ParameterError
        No folder, a file where the folder should be, a folder that cannot be written, a bound out of range.
    """

    folder: str | os.PathLike = ""
    _: KW_ONLY
    before_s: float = 5.0
    after_s: float = 5.0
    memory_mb: float = 512.0

    def __post_init__(self):
        if not str(self.folder):
            raise OptionError("ClipOptions.folder", "ClipOptions.folder needs a folder")
        object.__setattr__(self, "before_s", check_field("ClipOptions.before_s", self.before_s))
        object.__setattr__(self, "after_s", check_field("ClipOptions.after_s", self.after_s))
        object.__setattr__(self, "memory_mb", check_field("ClipOptions.memory_mb", self.memory_mb))

    def check(self) -> None:
        """The folder exists (created when missing, said in one line) and is writable; before anything starts."""
        from necviz.outputs import make_folder

        try:
            folder = os.fspath(make_folder(self.folder, "ClipOptions.folder"))
        except ParameterError as e:
            raise OptionError("ClipOptions.folder", str(e)) from None
        if not os.access(folder, os.W_OK):
            raise OptionError("ClipOptions.folder", f"ClipOptions.folder: folder {folder!r} is not writable")


@dataclass(frozen=True)
class VideoOptions:
    """``--video OUT.mp4``: an H.264 video of what the dashboard shows (:mod:`necviz.dashboard.video`).

    Parameters
    ----------
    path : path
        The ``.mp4`` to write (an existing one only with ``force``; never an input).
    speed : float, optional
        Video time per sensor time (0.1: ten times slower than real); ``None``: the run's own
        ``--speed`` when it is a number, else real time.
    fps : float
        Frames per second of the video.
    force : bool
        Replace an existing file.

    Raises
    ------
    ParameterError
        No path, a speed that is not a positive number, a frame rate out of range.
    """

    path: str | os.PathLike = ""
    _: KW_ONLY
    speed: float | None = None
    fps: float = 30.0
    force: bool = False

    def __post_init__(self):
        if not str(self.path):
            raise OptionError("VideoOptions.path", "VideoOptions.path needs a file name")
        if self.speed is not None:
            object.__setattr__(self, "speed", parse_speed(self.speed, "VideoOptions.speed"))
            if self.speed is None:
                raise OptionError(
                    "VideoOptions.speed",
                    "VideoOptions.speed for a video must be a number (0.1 is ten times slower than real time)",
                )
        object.__setattr__(self, "fps", check_field("VideoOptions.fps", self.fps))


@dataclass(frozen=True)
class DemoOptions:
    """``necviz demo``: every controller drives its own simulated camera; one scene, side by side.

    Parameters
    ----------
    scene : SceneOptions
        The simulated scene.
    controllers : tuple of str
        Registered controller names (default: ``nec``, ``nec-frames`` and the five baselines).
    record : path, optional
        Keep the first controller's camera in a native ``.necrec`` recording.
    force : bool
        Replace existing output files (never an input).
    profile : path, optional
        A camera profile for the controllers (default: the shipped simulator profile).
    show, tune : ShowOptions, TuneOptions
        Pacing and drawing; live tuning.
    clips : ClipOptions, optional
        The flight recorder.
    video : VideoOptions, optional
        Also write an MP4 of the dashboard.

    Raises
    ------
    ParameterError
        An unknown controller, a name given twice, a bad scene.
    """

    scene: SceneOptions = field(default_factory=SceneOptions)
    controllers: tuple = DEFAULT_CONTROLLERS
    _: KW_ONLY
    record: str | os.PathLike | None = None
    force: bool = False
    profile: str | os.PathLike | None = None
    show: ShowOptions = field(default_factory=ShowOptions)
    tune: TuneOptions = field(default_factory=TuneOptions)
    clips: ClipOptions | None = None
    video: VideoOptions | None = None

    def __post_init__(self):
        object.__setattr__(self, "controllers", parse_controllers(self.controllers, "DemoOptions.controllers"))

    def inputs(self) -> list:
        """The files the demo reads: a scenario file, a tuning file, a camera profile."""
        return [*_scene_inputs(self.scene, self.tune), self.profile]

    def check_outputs(self, viewer: ViewerOptions) -> None:
        """The files the demo writes (``record``, ``video``, the viewer's ``save``), checked before anything
        starts (:func:`necviz.outputs.check_run_files`); ``viewer``: resolved."""
        from necviz.outputs import check_run_files

        video = self.video.path if self.video is not None else None
        check_run_files({"--record": self.record, "--video": video}, viewer, self.inputs(), self.force)


@dataclass(frozen=True)
class ReplayOptions:
    """``necviz replay FILE``: a recording through P-TEDI and a controller in open loop.

    Parameters
    ----------
    file : path
        The recording (any format ``necviz info`` reads).
    start_s, end_s : float, optional
        Seconds from the recording's first timestamp.
    exposure_us : float, optional
        The exposure of formats that do not store one.
    format : str, optional
        Skip format detection.
    controller : str
        The controller shown in open loop (default ``nec``).
    json : path, optional
        Also write the summary (prediction errors, skill scores, saturated frames) as JSON.
    force : bool
        Replace existing output files (never the input).
    profile : path, optional
        A camera profile.
    show : ShowOptions
        Pacing and drawing.
    video : VideoOptions, optional
        Also write an MP4 of the dashboard.
    pipe_timeout_s : float, optional
        Accept a named pipe as ``file``, waiting at most this long for its data.

    Raises
    ------
    ParameterError
        No file, an unknown controller, a bad range or exposure.
    """

    file: str | os.PathLike = ""
    _: KW_ONLY
    start_s: float | None = None
    end_s: float | None = None
    exposure_us: float | None = None
    format: str | None = None
    controller: str = "nec"
    json: str | os.PathLike | None = None
    force: bool = False
    profile: str | os.PathLike | None = None
    show: ShowOptions = field(default_factory=ShowOptions)
    video: VideoOptions | None = None
    pipe_timeout_s: float | None = None  # accept a named pipe as FILE, waiting at most this long for data

    def __post_init__(self):
        if not str(self.file):
            raise OptionError("ReplayOptions.file", "ReplayOptions.file is empty: replay needs a recording file")
        object.__setattr__(self, "controller", parse_controllers([self.controller], "ReplayOptions.controller")[0])
        _check_reading(self, "ReplayOptions")
        if self.pipe_timeout_s is not None:
            object.__setattr__(self, "pipe_timeout_s", check_field("ReplayOptions.pipe_timeout_s", self.pipe_timeout_s))

    def inputs(self) -> list:
        """The files the replay reads: the recording, a camera profile."""
        return [self.file, self.profile]

    def check_outputs(self, viewer: ViewerOptions) -> None:
        """The files the replay writes (``json``, ``video``, the viewer's ``save``), checked before anything
        is opened (:func:`necviz.outputs.check_run_files`); ``viewer``: resolved."""
        from necviz.outputs import check_run_files

        video = self.video.path if self.video is not None else None
        check_run_files({"--json": self.json, "--video": video}, viewer, self.inputs(), self.force)


def _check_reading(options, owner: str) -> None:
    """``start_s``/``end_s``/``exposure_us``, read the same way by replay and export (the flag table's rules)."""
    start_s = None if options.start_s is None else check_field(f"{owner}.start_s", options.start_s)
    end_s = None if options.end_s is None else check_field(f"{owner}.end_s", options.end_s)
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise OptionError(f"{owner}.end_s", f"{owner}.end_s ({end_s} s) must come after {owner}.start_s ({start_s} s)")
    exposure_us = None if options.exposure_us is None else check_field(f"{owner}.exposure_us", options.exposure_us)
    object.__setattr__(options, "start_s", start_s)
    object.__setattr__(options, "end_s", end_s)
    object.__setattr__(options, "exposure_us", exposure_us)


@dataclass(frozen=True)
class ExportOptions:
    """``necviz export IN OUT``: a recording rewritten in the format OUT's suffix names.

    Parameters
    ----------
    file : str or os.PathLike
        The recording (any format ``necviz replay`` reads).
    out_path : str or os.PathLike
        The output: ``.aedat4``, ``.h5``/``.hdf5``, ``.npz`` or ``.necrec``.
    start_s, end_s : float, optional
        The cut, in seconds from the recording's first timestamp (as in replay).
    exposure_us : float, optional
        The exposure of input formats that do not store it (µs, > 0).
    format : str, optional
        The input's format (skips detection).
    compression : str, optional
        Packet compression of ``.aedat4`` (default ``lz4``) and ``.necrec`` (default ``zstd``):
        ``lz4``, ``zstd`` or ``none``; ``.h5`` and ``.npz`` have their own and refuse it.
    force : bool
        Replace an existing output (never the input).
    pipe_timeout_s : float, optional
        Accept a named pipe as ``file``, waiting at most this long for its data (copied first).

    Raises
    ------
    ParameterError
        No input or output named, or a bad range or exposure.
    """

    file: str | os.PathLike = ""
    out_path: str | os.PathLike = ""
    _: KW_ONLY
    start_s: float | None = None
    end_s: float | None = None
    exposure_us: float | None = None
    format: str | None = None
    compression: str | None = None
    force: bool = False
    pipe_timeout_s: float | None = None

    def __post_init__(self):
        if self.pipe_timeout_s is not None:
            object.__setattr__(self, "pipe_timeout_s", check_field("ExportOptions.pipe_timeout_s", self.pipe_timeout_s))
        if self.compression is not None and self.compression not in ("lz4", "zstd", "none"):
            raise OptionError(
                "ExportOptions.compression",
                f"ExportOptions.compression must be lz4, zstd or none, got {self.compression!r}",
            )
        if not str(self.file) or not str(self.out_path):
            field = "ExportOptions.file" if not str(self.file) else "ExportOptions.out_path"
            raise OptionError(field, f"{field} is empty: export needs a recording and an output file")
        _check_reading(self, "ExportOptions")


@dataclass(frozen=True)
class LiveOptions:
    """``necviz live``: a DAVIS camera (USB or emulated) with a controller closing the loop.

    Parameters
    ----------
    device : str
        ``usb`` (a DAVIS346/DAVIS240 on USB, necviz's driver), ``dv`` (the same camera through iniVation's
        dv-processing) or ``emulated`` (necviz's driver on a virtual DAVIS346).
    serial : str, optional
        The camera's serial number (default: the first found).
    reconnect : bool
        After an unplug, wait for the same camera and carry on.
    controller : str
        The controller closing the loop (default ``nec``).
    duration_s : float, optional
        Stop after this much sensor time (default: until Ctrl-C).
    scene : SceneOptions
        The emulated device's scene.
    emulate_unplug_s : float, optional
        Unplug the emulated device after this many seconds.
    usb : str
        How necviz's driver reads the bulk endpoint: ``single`` (default: one 256 KiB read in flight), ``auto``
        (``libusb1`` if installed, else ``pyusb``), ``libusb1`` or ``pyusb``
        (:mod:`necviz.drivers.davis.transfers`).
    usb_transfers : (int, int), optional
        Transfers in flight and bytes each for the rings (default 32 x 8192).
    record : path, optional
        Keep the session in a native ``.necrec`` recording.
    force : bool
        Replace existing output files.
    profile : path, optional
        A camera profile.
    history : int
        Frames of per-frame telemetry kept (a live run may last hours).
    show, tune : ShowOptions, TuneOptions
        Pacing and drawing; live tuning.
    clips : ClipOptions, optional
        The flight recorder.
    json : path, optional
        Write the run's summary per lane (frames, saturated frames, events, commands, processing latency,
        the reaction in sensor time) as JSON; an existing file is replaced only with ``force``.

    Raises
    ------
    ParameterError
        An unknown device or controller, a bad duration.
    """

    device: str = "usb"
    _: KW_ONLY
    serial: str | None = None
    reconnect: bool = False
    controller: str = "nec"
    duration_s: float | None = None
    scene: SceneOptions = field(default_factory=SceneOptions)  # the emulated device's scene
    emulate_unplug_s: float | None = None
    usb: str = "single"
    usb_transfers: tuple[int, int] | None = None
    record: str | os.PathLike | None = None
    force: bool = False
    profile: str | os.PathLike | None = None
    history: int = 3_000  # frames of per-frame telemetry kept (a live run may last hours)
    show: ShowOptions = field(default_factory=ShowOptions)
    tune: TuneOptions = field(default_factory=TuneOptions)
    clips: ClipOptions | None = None
    json: str | os.PathLike | None = None

    def __post_init__(self):
        if self.device not in ("usb", "dv", "emulated"):
            raise OptionError(
                "LiveOptions.device", f"LiveOptions.device must be usb, dv or emulated, got {self.device!r}"
            )
        object.__setattr__(self, "controller", parse_controllers([self.controller], "LiveOptions.controller")[0])
        if self.duration_s is not None:
            object.__setattr__(self, "duration_s", check_field("LiveOptions.duration_s", self.duration_s, "live"))
        if self.emulate_unplug_s is not None:
            object.__setattr__(
                self, "emulate_unplug_s", check_field("LiveOptions.emulate_unplug_s", self.emulate_unplug_s)
            )
        try:
            object.__setattr__(self, "history", check_number("LiveOptions.history", self.history, 1, integer=True))
        except ParameterError as e:
            raise OptionError("LiveOptions.history", str(e)) from None
        from necviz.drivers.davis.transfers import check_transfers, resolve_usb

        if self.device == "dv" and (self.usb != "single" or self.usb_transfers is not None):
            raise OptionError(
                "LiveOptions.usb",
                "LiveOptions.usb and LiveOptions.usb_transfers set necviz's driver (LiveOptions.device usb or "
                "emulated), not LiveOptions.device dv",
            )
        if self.usb == "single" and self.usb_transfers is not None:  # would be half ignored: say so instead
            raise OptionError(
                "LiveOptions.usb_transfers",
                "LiveOptions.usb_transfers sets the rings (LiveOptions.usb libusb1, pyusb or auto); the single read "
                "keeps one 256 KiB transfer in flight",
            )
        try:
            if self.device != "dv":
                resolve_usb(self.usb)  # libusb1 asked for and not installed: refused here, in one line
            if self.usb_transfers is not None:
                n, size = self.usb_transfers
                object.__setattr__(self, "usb_transfers", check_transfers(n, size))
        except OptionError:
            raise
        except ParameterError as e:
            raise OptionError(
                "LiveOptions.usb_transfers" if self.usb_transfers is not None else "LiveOptions.usb", str(e)
            ) from None

    def inputs(self) -> list:
        """The files the session reads: the emulated scene's scenario file, a tuning file, a camera profile."""
        return [*_scene_inputs(self.scene, self.tune), self.profile]

    def check_outputs(self, viewer: ViewerOptions) -> None:
        """The files the session writes (``record``, ``json``, the viewer's ``save``), checked before the
        camera is opened (:func:`necviz.outputs.check_run_files`); ``viewer``: resolved."""
        from necviz.outputs import check_run_files

        check_run_files({"--record": self.record, "--json": self.json}, viewer, self.inputs(), self.force)


@dataclass(frozen=True)
class CompareOptions:
    """``necviz compare``: every controller in closed loop on one simulated scene, over seeds.

    Parameters
    ----------
    scene : SceneOptions
        The simulated scene; seeds run from its seed on.
    controllers : tuple of str
        Registered controller names (default: NEC, its ablations and the five baselines).
    seeds : int
        Independent replicates: every metric is reported as a mean with a 95 % confidence interval.
    sift : bool
        Count SIFT inliers between consecutive frames (most of the run time).
    json, save : path, optional
        Write the table as JSON; the first seed's recording as ``.rrd``.
    force : bool
        Replace existing output files (never an input).
    profile : path, optional
        A camera profile for the controllers.
    controller_params : dict
        ``{controller: {parameter: value}}`` (``--param NAME.KEY=VALUE``).
    sim : dict
        Simulator overrides ``{"dvs.KEY" | "aps.KEY": value}`` (``--sim``).
    markers : bool
        Detect the scene's fiducial markers on every frame.

    Raises
    ------
    ParameterError
        An unknown controller or parameter, a seed count out of range.
    """

    scene: SceneOptions = field(default_factory=SceneOptions)
    controllers: tuple = COMPARE_CONTROLLERS
    _: KW_ONLY
    seeds: int = 1
    sift: bool = True
    json: str | os.PathLike | None = None
    save: str | os.PathLike | None = None
    force: bool = False
    profile: str | os.PathLike | None = None
    controller_params: dict = field(default_factory=dict)  # {controller: {param: value}} (--param NAME.KEY=VALUE)
    sim: dict = field(default_factory=dict)  # simulator overrides {"dvs.c_on": 0.3, ...} (--sim KEY=VALUE)
    markers: bool = False  # detect the scene's fiducial markers on every frame (--markers)

    def __post_init__(self):
        object.__setattr__(self, "controllers", parse_controllers(self.controllers, "CompareOptions.controllers"))
        object.__setattr__(self, "seeds", check_field("CompareOptions.seeds", self.seeds))
        object.__setattr__(self, "controller_params", {k: dict(v) for k, v in (self.controller_params or {}).items()})
        check_param_lanes(self.controller_params, self.controllers, "CompareOptions.controller_params")
        object.__setattr__(self, "sim", dict(self.sim or {}))


__all__ = [
    "BASELINES",
    "ClipOptions",
    "VideoOptions",
    "NUMBER_FLAGS",
    "NumberRule",
    "check_flag",
    "controller_kind",
    "number",
    "parse_memory_limit",
    "COMPARE_CONTROLLERS",
    "CompareOptions",
    "DEFAULT_CONTROLLERS",
    "DemoOptions",
    "ExportOptions",
    "LAYOUT_NAMES",
    "LiveOptions",
    "ReplayOptions",
    "SceneOptions",
    "ShowOptions",
    "TuneOptions",
    "ViewerOptions",
    "parse_controllers",
    "parse_setting",
    "parse_speed",
]
