"""A DAVIS camera through iniVation's own dv-processing, as a :class:`~necviz.drivers.source.Source`.

``necviz live --device dv`` runs on ``dv_processing.io.camera.DAVIS`` (dv-processing 2.x, built on the
vendor's libcaer, tested by the vendor on real hardware) instead of necviz's pyusb driver, so a user with a
camera does not depend on one unproven path. It needs the optional extra: ``pip install "necviz[dv]"``.

:class:`DvCamera` adapts anything with dv-processing's input interface — ``getNextEventBatch``,
``getNextFrame``, ``getNextImuBatch``, ``getNextTriggerBatch``, ``isRunning``, ``getEventResolution`` — which
the live camera and the vendor's recording reader (``dv_processing.io.MonoCameraRecording``) share; the tests
run it over the reader on a real recording, so everything but the setters is checked on real data.

Conversions: events (``EventStore.numpy()``: timestamp, x, y, polarity 0/1) → ``EVENT_DTYPE`` with ``p = ±1``;
frames (``timestamp`` = exposure start, ``exposure``, ``image``, ``positionX/Y``) → :class:`Frame` on the full
sensor (a ROI placed at its position), 8-bit grey (``ColorMode.GRAYSCALE`` makes dv-processing demosaic a
colour sensor, as libcaer's grey frame mode does); IMU samples (g, °/s, °C, the units dv-processing keeps);
triggers (dv's ``TriggerType`` values are :data:`~necviz.core.imu.TRIGGER_KINDS` in the same order, the APS
frame and exposure ones included). Times are dv-processing's (Unix µs for a camera).

Stream order. dv-processing delivers a frame only after its readout, and each stream separately; necviz's
sources deliver exposure markers in stream order, before the events they bound. Packets therefore go through
:class:`~necviz.drivers.recordings.reader.StreamAssembler` (markers made from each frame's own exposure, so
they match it exactly), released up to a watermark:

* a recording (``live=False``): the stream pulled next is the one whose last packet is earliest, and the
  watermark is the earliest of the streams' last times (exact);
* a camera (``live=True``): every stream is drained, and the watermark is the latest time seen — held back
  to the start of any exposure the camera has announced (trigger ``APS_EXPOSURE_START``) whose frame has not
  arrived yet, or, if the camera announces none, by twice the largest delay seen between an exposure start
  and its frame's arrival (at least one frame interval). Events during an exposure thus reach the controller
  when its frame arrives, up to exposure + readout later than with the pyusb driver; a frame arriving after
  events past its start were released is dropped and counted (``frames_late``).

Commands: :meth:`DvCamera.set_exposure` calls ``setExposureDuration`` and keeps the command; a frame whose
exposure (µs) matches it marks it applied (:class:`~necviz.drivers.command_log.CommandLog`) and carries its digital
gain, as with the pyusb driver. :meth:`DvCamera.set_frame_interval` calls ``setFrameInterval``.

DVS biases (issue 29): :meth:`DvCamera.set_dvs_biases` takes the same libcaer bias words as necviz's driver
(:mod:`necviz.core.biases`) and sets each through dv-processing's coarse/fine setter
(``DAVIS.setDavis346BiasCoarseFine`` / ``setDavis240BiasCoarseFine`` with its ``Davis346BiasCF`` /
``Davis240BiasCF`` member; dv-processing ``include/dv-processing/io/camera/davis.hpp``). Those setters take
coarse and fine only: the word's flag bits stay as the camera has them (libcaer's defaults for every DVS bias).
A bias dv-processing has no setter for (``IFREFRBN``, ``IFTHRBN``) is refused in one line and nothing is
written. The FPGA filters go through ``setBackgroundActivityFilter`` / ``setRefractoryPeriodFilter`` (250 µs
steps); these setters take a time and cannot switch a filter off, so "off" is refused.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Iterator

import numpy as np

from necviz.core.biases import BIAS_ADDRESSES, FILTER_STEP_US, CoarseFine, family_of
from necviz.core.control.controller import CameraLimits
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, TRIGGER_KINDS
from necviz.core.sensor import SensorGeometry, known_event_rate_max
from necviz.core.stream import packet_time_us
from necviz.drivers.command_log import CommandedCamera, CommandLog, check_command, with_gain
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.camera import DIGITAL_GAIN_MAX, READOUT_ALLOWANCE_US, CameraOptions
from necviz.drivers.davis.device import DeviceInfo
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError, DeviceNotFoundError
from necviz.drivers.recordings.reader import StreamAssembler, sensor_from_chip, to_gray8
from necviz.drivers.source import CAMERA, CameraInfo, Source, route

#: the one line that says how to get this backend
DV_INSTALL = "--device dv needs iniVation's dv-processing: pip install 'necviz[dv]'"
#: dv-processing's TriggerType values of the APS exposure start and end (libcaer's special events 16, 17)
_APS_EXPOSURE_START, _APS_EXPOSURE_END = 8, 9
#: a frame's exposure (µs, from its timestamps) within this of a command's, or this fraction, is that command
ECHO_TOLERANCE_US = 2.0
ECHO_TOLERANCE_REL = 5e-3
#: an announced exposure whose frame has not come after this long (µs of stream) is given up (frame lost)
ANNOUNCED_TIMEOUT_US = 500_000
POLL_S = 0.001
#: necviz's (libcaer's) coarse/fine bias names -> the member of dv-processing's ``Davis346BiasCF`` /
#: ``Davis240BiasCF`` enum that names the same bias (a name the chip's enum lacks has no setter)
DV_BIAS_MEMBERS = {
    "LOCALBUFBN": "LocalBuffer",
    "PADFOLLBN": "PadFollower",
    "DIFFBN": "Diff",
    "ONBN": "On",
    "OFFBN": "Off",
    "PIXINVBN": "PixelInverter",
    "PRBP": "Photoreceptor",
    "PRSFBP": "PhotoreceptorSourceFollower",
    "REFRBP": "Refractory",
    "READOUTBUFBP": "ReadoutBuffer",
    "APSROSFBN": "ApsReadoutSourceFollower",
    "ADCCOMPBP": "ADCComparator",
    "COLSELLOWBN": "COLSelectLow",
    "DACBUFBP": "DACBuffer",
    "LCOLTIMEOUTBN": "LCOLTimeout",
    "AEPDBN": "AERPullDown",
    "AEPUXBP": "AERPullUpX",
    "AEPUYBP": "AERPullUpY",
    "BIASBUFFER": "BiasBuffer",
    "APSCASEPC": "ApsCascode",
    "DIFFCASBNC": "DiffCascode",
    "APSOVERFLOWLEVELBN": "ApsOverflowLevel",
}
#: the FPGA filters at libcaer's defaults, as the camera opens (µs; ``None`` = off): background activity 2 ms,
#: refractory off (``davisCommonSendDefaultFPGAConfig``)
DEFAULT_FILTERS_US = (8 * FILTER_STEP_US, None)


def import_dv():
    """The ``dv_processing`` module, or a one-line :class:`DeviceError` saying how to install it."""
    try:
        import dv_processing
    except ImportError:
        raise DeviceError(DV_INSTALL) from None
    return dv_processing


def find_dv_cameras() -> list[DeviceInfo]:
    """DAVIS cameras dv-processing finds (empty if it is not installed or finds none)."""
    try:
        dv = import_dv()
        found = dv.io.camera.DAVIS.findDevices()
    except (DeviceError, RuntimeError):
        return []
    return [
        DeviceInfo(
            str(d.cameraModel) if d.cameraModel else "DAVIS",
            str(d.serialNumber),
            int(d.firmwareVersion),
            None,
            int(d.busNumber),
            int(d.devAddress),
            backend="dv",
        )
        for d in found
    ]


def open_dv_camera(serial: str | None = None, *, options: CameraOptions | None = None) -> DvCamera:
    """Open a DAVIS camera through dv-processing and configure its exposure and frame interval.

    Raises
    ------
    DeviceError
        dv-processing is not installed (the line says how to install it), or it could not open the camera.
    DeviceNotFoundError
        No DAVIS camera (or none with ``serial``) is attached.
    """
    dv = import_dv()
    found = dv.io.camera.DAVIS.findDevices()
    if serial is not None:
        found = [d for d in found if str(d.serialNumber) == serial]
    if not found:
        which = f" with serial {serial}" if serial else ""
        raise DeviceNotFoundError(f"dv-processing finds no DAVIS camera{which}\n" + P.UDEV_HINT)
    try:
        cam = dv.io.camera.DAVIS(found[0])
        cam.setColorMode(dv.io.camera.DAVIS.ColorMode.GRAYSCALE)
    except RuntimeError as e:
        raise DeviceError(f"dv-processing could not open DAVIS {found[0].serialNumber}: {e}") from None
    return DvCamera(cam, live=True, options=options)


def _us(td) -> int:
    """µs of a ``datetime.timedelta`` (dv-processing's durations) or of a number."""
    if isinstance(td, _dt.timedelta):
        return td.days * 86_400_000_000 + td.seconds * 1_000_000 + td.microseconds
    return int(td)


def _events(store) -> np.ndarray:
    a = store.numpy()
    ev = np.empty(a.shape[0], EVENT_DTYPE)
    ev["t"] = a["timestamp"]
    ev["x"] = a["x"]
    ev["y"] = a["y"]
    ev["p"] = a["polarity"].astype(np.int8) * 2 - 1
    return ev


def _imu(samples) -> np.ndarray:
    out = np.empty(len(samples), IMU_DTYPE)
    for i, s in enumerate(samples):  # at most a few per ms: no per-event work
        out[i] = (
            s.timestamp,
            s.accelerometerX,
            s.accelerometerY,
            s.accelerometerZ,
            s.gyroscopeX,
            s.gyroscopeY,
            s.gyroscopeZ,
            s.temperature,
        )
    return out


class DvCamera(CommandedCamera, Source):
    """A DAVIS camera (or a dv-processing recording reader) as a :class:`~necviz.drivers.source.Source`.

    Parameters
    ----------
    reader
        A ``dv_processing.io.camera.DAVIS`` (``live=True``) or anything with its input interface, e.g.
        ``dv_processing.io.MonoCameraRecording`` (``live=False``).
    live : bool
        Poll every stream and hold back only as the module docstring says (a camera), or merge the streams
        exactly (a file).
    options : CameraOptions, optional
        The exposure and frame interval configured before streaming (a camera) and the batch period; default
        ``CameraOptions()``.

    Attributes: ``sensor``, ``info`` (backend, serial, firmware, logic version where dv-processing reports them),
    ``limits``, ``state`` ("ready", "streaming", "finished", "disconnected", "closed"), ``stats``.
    """

    cameras = (CAMERA,)

    def __init__(self, reader, *, live: bool = True, options: CameraOptions | None = None):
        options = CameraOptions() if options is None else options
        if not isinstance(options, CameraOptions):
            raise ParameterError(f"DvCamera takes CameraOptions, got {type(options).__name__}")
        self.options = options
        self.live = bool(live)
        self._reader = reader
        name = str(_call(reader, "getCameraName", "") or "")
        res = _call(reader, "getEventResolution") or _call(reader, "getFrameResolution")
        if res is None:
            raise DeviceError(f"dv-processing input {name or '?'} reports no event or frame resolution")
        geo = sensor_from_chip(name)
        w, h = int(res[0]), int(res[1])
        self.sensor = geo if geo is not None and geo.shape == (h, w) else SensorGeometry(w, h, name or "DAVIS")
        self.frame_interval_us = float(options.frame_interval_us)
        self.limits = CameraLimits(
            exposure_min_us=10.0,
            exposure_max_us=float(min(P.EXPOSURE_MAX_US, self.frame_interval_us - READOUT_ALLOWANCE_US)),
            gain_max=DIGITAL_GAIN_MAX,
        )
        self.info = {
            "backend": "dv",
            "kind": self.sensor.name,
            "serial": str(_call(reader, "getSerialNumber", "") or name.rpartition("_")[2] or "?"),
            "firmware": _call(reader, "getFirmwareVersion"),
            "logic": _call(reader, "getLogicVersion"),
            "logic_version": _call(reader, "getLogicVersion"),
        }
        self._commands = CommandLog(ECHO_TOLERANCE_US, ECHO_TOLERANCE_REL)
        self._exposure_us = float(self.limits.clamp(options.exposure_us, 1.0)[0])
        self._last_t = 0
        self.state = "ready"
        self._closed = False
        self._iterating = False
        self.counts = {"events": 0, "frames": 0, "imu_samples": 0, "triggers": 0, "exposures_without_frame": 0}
        self._asm: StreamAssembler | None = None
        self._filters: tuple[float | None, float | None] = DEFAULT_FILTERS_US
        self._dvs_applied: int | None = None
        if self.live and hasattr(reader, "setExposureDuration"):
            self._set_device_exposure(self._exposure_us)
            self.set_frame_interval(self.frame_interval_us)

    # -- source interface ---------------------------------------------------------------------------------
    def packets(self) -> Iterator:
        """``(camera, packet)`` pairs (:class:`~necviz.drivers.source.Source`); iterate the camera for bare packets."""
        return route(CAMERA, self)

    @property
    def camera_info(self) -> CameraInfo:
        return CameraInfo(self.limits, None, known_event_rate_max(self.sensor), self.frame_interval_us)

    def warm_up(self) -> None:
        """Nothing to compile: the conversions are NumPy."""

    def __iter__(self) -> Iterator:
        if self._iterating or self._closed:
            raise ParameterError("a DvCamera can be iterated once (open a new one to read again)")
        self._iterating = True
        self._asm = StreamAssembler(self.sensor, batch_us=self.options.batch_us)
        self.state = "streaming"
        try:
            feed = self._live() if self.live else self._file()
            for pk in feed:
                if isinstance(pk, Frame):
                    pk = self._apply_command(pk)
                    self._last_t = max(self._last_t, int(pk.exposure_end_us))
                else:
                    t = packet_time_us(pk)
                    if t is not None:
                        self._last_t = max(self._last_t, t)
                yield pk
        finally:
            self.close()

    def set_exposure(
        self, camera: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None:
        """Command exposure (µs, clamped to ``limits``; ``setExposureDuration``) and digital gain (1..8).

        On a recording reader (no setters) the command is only kept: replay is open loop."""
        exp, g = self.limits.clamp(*check_command(camera, exposure_us, gain))
        t = self._last_t if issue_time_us is None else int(issue_time_us)
        if hasattr(self._reader, "setExposureDuration"):
            self._set_device_exposure(exp)
        self._exposure_us = exp
        self._commands.issue(t, exp, g, round(exp))

    def set_frame_interval(self, interval_us: float) -> None:
        """Time between frame starts (µs; ``setFrameInterval``); the longest exposure follows it."""
        us = float(interval_us)
        if not (2 * READOUT_ALLOWANCE_US <= us <= P.FRAME_INTERVAL_MAX_US):
            raise ParameterError(f"frame interval must be {2 * READOUT_ALLOWANCE_US}..{P.FRAME_INTERVAL_MAX_US} µs")
        if hasattr(self._reader, "setFrameInterval"):
            try:
                self._reader.setFrameInterval(_dt.timedelta(microseconds=round(us)))
            except RuntimeError as e:
                raise DeviceError(f"dv-processing: setting the frame interval failed: {e}") from None
        self.frame_interval_us = us
        self.limits = CameraLimits(
            exposure_min_us=10.0,
            exposure_max_us=float(min(P.EXPOSURE_MAX_US, us - READOUT_ALLOWANCE_US)),
            gain_max=DIGITAL_GAIN_MAX,
        )

    @property
    def exposure_us(self) -> float:
        return self._exposure_us

    @property
    def stats(self) -> dict:
        """Packets delivered, frames dropped by the stream merge (``frames_late``, ``frames_overlap``...),
        announced exposures whose frame never came, commands."""
        out = dict(self.counts)
        if self._asm is not None:
            out.update({k: int(v) for k, v in self._asm.counts.items()})
        out["commands_issued"] = self.commands_issued
        return out

    def close(self) -> None:
        """Release the camera (dv-processing stops it when its object goes). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._reader = None
        if self.state not in ("finished", "disconnected"):
            self.state = "closed"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- DVS biases and filters (issue 29) -----------------------------------------------------------
    @property
    def dvs_family(self) -> str:
        """The bias table the chip uses: ``"DAVIS240"`` or ``"DAVIS346"``."""
        return family_of(self.sensor.name)

    def _dv_setter(self, what: str):
        """``reader.what`` on a live camera, else a one-line refusal (a recording is replayed as it was)."""
        fn = getattr(self._reader, what, None) if self.live else None
        if not callable(fn):
            raise ParameterError(f"this dv-processing input has no {what} (a recording is replayed as it was)")
        return fn

    takes_dvs_biases = True

    def set_dvs_biases(self, words: dict[int, int]) -> None:
        """Write DVS bias words (module-5 parameter -> libcaer word, :mod:`necviz.core.biases`) through
        dv-processing's coarse/fine setter, one call per bias. Every bias is checked before any is written: one
        without a setter refuses the whole change."""
        fam = self.dvs_family
        setter = self._dv_setter(f"set{fam.capitalize()}BiasCoarseFine")
        enum = getattr(type(self._reader), f"{fam.capitalize()}BiasCF", None) or getattr(
            self._reader, f"{fam.capitalize()}BiasCF", None
        )
        names = {a: n for n, a in BIAS_ADDRESSES[fam].items()}
        calls = []
        for addr, word in sorted(words.items()):
            name = names.get(int(addr), f"bias {addr}")
            member = getattr(enum, DV_BIAS_MEMBERS.get(name, ""), None) if enum is not None else None
            if member is None:
                raise ParameterError(
                    f"dv-processing has no setter for the {fam}'s bias {name}; nothing was written "
                    "(necviz's own driver, --device davis, writes every bias)"
                )
            cf = CoarseFine.parse(int(word))
            calls.append((member, cf.coarse, cf.fine))
        try:
            for member, coarse, fine in calls:
                setter(member, coarse, fine)
        except RuntimeError as e:
            raise DeviceError(f"dv-processing: setting the biases failed: {e}") from None
        self._dvs_applied = self._last_t

    def set_dvs_filters(self, background_activity_us: float | None, refractory_us: float | None) -> None:
        """The FPGA's background-activity and refractory filters (µs, 250 µs steps; ``None`` = off, which
        dv-processing's setters cannot do: refused). Only a filter that changed is written."""
        new = (background_activity_us, refractory_us)
        todo = []
        for what, old, value in zip(
            ("setBackgroundActivityFilter", "setRefractoryPeriodFilter"), self._filters, new, strict=True
        ):
            if value == old:
                continue
            if value is None:
                raise ParameterError(
                    f"dv-processing's {what} takes a time and cannot switch the filter off; nothing was written"
                )
            todo.append((self._dv_setter(what), int(round(float(value) / FILTER_STEP_US))))
        try:
            for fn, steps in todo:
                fn(steps)
        except RuntimeError as e:
            raise DeviceError(f"dv-processing: setting the DVS filters failed: {e}") from None
        self._filters = new
        self._dvs_applied = self._last_t

    def dvs_applied_us(self) -> int | None:
        """Stream time from which the last DVS change holds: the last packet delivered when it was written (a
        lower bound: the data already in flight was produced before)."""
        return self._dvs_applied

    # -- reading ----------------------------------------------------------------------------------------
    def _set_device_exposure(self, us: float) -> None:
        try:
            self._reader.setExposureDuration(_dt.timedelta(microseconds=round(us)))
        except RuntimeError as e:
            raise DeviceError(f"dv-processing: setting the exposure failed: {e}") from None

    def _pull(self, kind: str) -> int | None:
        """Read one packet of stream ``kind`` into the assembler; its last time, or None if it had none."""
        r, asm = self._reader, self._asm
        if kind == "events":
            store = r.getNextEventBatch()
            if store is None:
                return None
            ev = _events(store)
            self.counts["events"] += ev.size
            asm.push_events(ev)
            return int(ev["t"][-1]) if ev.size else -1
        if kind == "frames":
            f = r.getNextFrame()
            if f is None:
                return None
            frame = self._frame(f)
            if frame is None:
                return -1
            self._frame_arrived(frame)
            asm.push_frame(frame)
            return int(frame.exposure_start_us)
        if kind == "imu":
            batch = r.getNextImuBatch()
            if batch is None:
                return None
            imu = _imu(batch)
            self.counts["imu_samples"] += imu.size
            asm.push_imu(imu)
            return int(imu["t"].max()) if imu.size else -1
        batch = r.getNextTriggerBatch()
        if batch is None:
            return None
        keep, last = [], -1
        for trig in batch:
            k, t = int(trig.type), int(trig.timestamp)
            last = max(last, t)
            if k < len(TRIGGER_KINDS):
                keep.append((t, k))
            if k == _APS_EXPOSURE_START:
                self._announced.append(t)
        if keep:
            self.counts["triggers"] += len(keep)
            asm.push_triggers(np.array(keep, TRIGGER_DTYPE))
        return last

    def _frame(self, f) -> Frame | None:
        """A dv frame as a necviz :class:`Frame` (None: an exposure of 0 µs, which cannot be announced)."""
        s = int(f.timestamp)
        exp = _us(f.exposure)
        if exp <= 0:
            self.counts["frames_no_exposure"] = self.counts.get("frames_no_exposure", 0) + 1
            return None
        img = to_gray8(np.asarray(f.image))
        x0, y0 = int(f.positionX), int(f.positionY)
        if img.shape != self.sensor.shape or x0 or y0:
            full = np.zeros(self.sensor.shape, np.uint8)
            h = min(img.shape[0], self.sensor.height - y0)
            w = min(img.shape[1], self.sensor.width - x0)
            full[y0 : y0 + h, x0 : x0 + w] = img[:h, :w]
            img = full
        self.counts["frames"] += 1
        return Frame(img, s, s + exp, 1.0, self.counts["frames"] - 1)

    def _frame_arrived(self, frame: Frame) -> None:
        s = int(frame.exposure_start_us)
        self._announced = [a for a in self._announced if a != s]

    def _file(self) -> Iterator:
        """Exact merge of a recording's streams: pull the stream that is furthest behind."""
        self._announced: list[int] = []
        last = {k: -(1 << 62) for k in ("events", "frames", "imu", "triggers")}
        while last:
            kind = min(last, key=last.get)
            t = self._pull(kind)
            if t is None:
                del last[kind]
            elif t >= 0:
                last[kind] = max(last[kind], t)
            if last:
                yield from self._asm.drain(min(last.values()))
        yield from self._asm.drain(None)
        self.state = "finished"

    def _live(self) -> Iterator:
        """A camera: drain every stream, release up to the watermark of the module docstring."""
        self._announced = []
        asm = self._asm
        horizon, lag, announcing = None, 0, False
        while not self._closed:
            got = False
            for kind in ("events", "frames", "imu", "triggers"):
                while True:
                    t = self._pull(kind)
                    if t is None:
                        break
                    got = True
                    if t >= 0:
                        horizon = t if horizon is None else max(horizon, t)
                        if kind == "frames":
                            lag = max(lag, asm.lag_of(t))
            announcing = announcing or bool(self._announced)
            if horizon is not None:
                waiting = [a for a in self._announced if horizon - a < ANNOUNCED_TIMEOUT_US]
                self.counts["exposures_without_frame"] += len(self._announced) - len(waiting)
                self._announced = waiting
                if announcing:
                    w = min([horizon + 1] + self._announced)
                else:
                    w = horizon - max(2 * lag, int(self.frame_interval_us))
                yield from asm.drain(w)
            if got:
                continue
            reader = self._reader
            if reader is None or not reader.isRunning() or getattr(reader, "stream_finished", False):
                self.counts["exposures_without_frame"] += len(self._announced)
                self._announced = []
                yield from asm.drain(None)
                if reader is not None and not getattr(reader, "stream_finished", False) and not self._closed:
                    self.state = "disconnected"
                    raise DeviceDisconnectedError(f"DAVIS {self.info['serial']} (dv-processing) stopped streaming")
                self.state = "finished"
                return
            time.sleep(POLL_S)

    def _apply_command(self, frame: Frame) -> Frame:
        """Mark the command this frame was exposed with (its exposure in µs) applied; apply its digital gain."""
        return with_gain(frame, self._commands.frame(int(frame.exposure_start_us), float(frame.exposure_us)))


def _call(obj, name: str, default=None):
    """``obj.name()`` if ``obj`` has it (a camera and a recording reader do not offer the same getters)."""
    fn = getattr(obj, name, None)
    if fn is None:
        return default
    try:
        return fn()
    except (RuntimeError, TypeError):
        return default


__all__ = ["DV_INSTALL", "DvCamera", "find_dv_cameras", "import_dv", "open_dv_camera"]
