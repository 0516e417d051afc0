"""The live DAVIS camera as a :class:`~necviz.drivers.source.Source`: ``open_camera`` and :class:`DavisCamera`.

Iterating a :class:`DavisCamera` runs the start sequence, reads the bulk endpoint on a thread
(a ring of bulk transfers in flight, :mod:`.transfers`, into the queue of :class:`~.device.BulkReader`), decodes each transfer (:class:`~.decoder.DavisDecoder`) and yields
packets in stream order: event batches (:class:`~necviz.core.events.EventBatch`, at most 1 ms and
65,536 events each, so a controller can act between frames), ``ExposureMarker('start')``, ``ExposureMarker('end')``, then the :class:`Frame`,
plus ``ImuBatch``/``TriggerBatch``.

Exposure and gain: :meth:`DavisCamera.set_exposure` clamps to :attr:`DavisCamera.limits` and writes
APS EXPOSURE = ``round(exposure_us x ADC clock MHz)`` (the device's actual clock). The DAVIS has no
analog gain, so ``gain`` is applied digitally: ``Frame.image = clip(round(Z8 x gain), 0, 255)`` with
``Z8 = CDS10 >> 2`` and ``Frame.gain = gain``. A command applies from the first frame that starts
after it was issued and was exposed with its register value (each frame reports its exposure in
ADC cycles, its *echo*; an echo within :data:`ECHO_TOLERANCE_CYCLES` of the register counts, see
:mod:`necviz.drivers.command_log`); that frame's start is the command's ``applied_start_us``. Memory
stays bounded over a long session (:class:`~necviz.drivers.command_log.CommandLog`).

Loss and lag: the reader thread decodes each transfer and queues at most :attr:`CameraOptions.buffer_s` (0.1 s) of
sensor time beyond what the consumer has taken, so a consumer that pauses briefly (a GC pause, a slow viewer) loses
nothing, and one that falls behind never works on data seconds old: past the bound the reader stops reading and the
device drops whole DVS events and counts them — ``stats["dropped_events"]``; ``stats["backpressure_s"]`` and
``backpressure_events`` say how long and how often the reader held back, ``lag_peak_us`` the deepest backlog in
sensor time (see :class:`~.device.BulkReader`).

Unplugging: every packet already decoded is yielded, then iteration raises
:class:`~.errors.DeviceDisconnectedError` — unless ``CameraOptions(reconnect=True)``: then ``state`` becomes
``"waiting"``, discovery is polled every 0.5 s for the same serial, the start sequence runs again
(with the last commanded exposure) and packets continue with timestamps offset to keep increasing.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from necviz.core.checks import check_number
from necviz.core.control.controller import CameraLimits
from necviz.core.errors import NecvizError, ParameterError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry, known_event_rate_max
from necviz.drivers.command_log import CommandedCamera, CommandLog, check_command, with_gain
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.color import COLOR_FILTERS
from necviz.drivers.davis.decoder import DavisDecoder, DecoderOptions
from necviz.drivers.davis.device import BulkReader, DavisDevice, open_device, usb_backend
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError, DeviceNotFoundError
from necviz.drivers.davis.transfers import (
    DEFAULT_TRANSFER_BYTES,
    DEFAULT_TRANSFERS,
    SINGLE_TRANSFER_BYTES,
    USB_CHOICES,
    check_transfers,
    make_reader,
    resolve_usb,
)
from necviz.drivers.source import CAMERA, CameraInfo, Source, route

if TYPE_CHECKING:
    from necviz.drivers.davis.emulator import EmulatorOptions, Faults

#: digital gain limit of the live camera (linear)
DIGITAL_GAIN_MAX = 8.0
#: reader counters that are peaks (kept as the maximum over connections, not summed)
_PEAKS = ("queue_peak_bytes", "lag_peak_us")
#: readout time kept free in each frame interval when limiting the exposure (µs)
READOUT_ALLOWANCE_US = 1000
RECONNECT_POLL_S = 0.5
#: An exposure echo (the ADC cycles a frame reports) within this many cycles of a command's register value, or
#: :data:`ECHO_TOLERANCE_REL` of it, counts as that command: the logic's report need not equal the register
#: exactly, and libcaer never compares the two (its auto-exposure only reads the echo, ``autoexposure.c``).
ECHO_TOLERANCE_CYCLES = 2
ECHO_TOLERANCE_REL = 1e-3


@dataclass(frozen=True)
class CameraOptions:
    """How a :class:`DavisCamera` streams (validated here, once).

    Parameters
    ----------
    reconnect : bool
        On unplugging, wait for the same serial to come back instead of raising
        :class:`~.device_errors.DeviceDisconnectedError` (module docstring).
    exposure_us : float
        The exposure configured before streaming (µs; clamped to the camera's limits).
    frame_interval_us : float
        Time between frame starts (µs), ``2 * READOUT_ALLOWANCE_US .. FRAME_INTERVAL_MAX_US``; the
        longest exposure is this minus :data:`READOUT_ALLOWANCE_US`.
    batch_us : int
        Event batches are cut at multiples of this many µs (so a controller can act between frames).
    usb : str
        How the bulk endpoint is read (:mod:`.transfers`): ``"single"`` (default: one read of 256 KiB in flight
        on the reader's thread), ``"auto"`` (``libusb1`` if the package is installed, else ``pyusb``),
        ``"libusb1"`` (asynchronous transfers in flight, as libcaer) or ``"pyusb"`` (synchronous reads on a thread
        of their own, a ring of buffers to the decoder). The rings are not the default: on the emulated camera
        they keep NEC's exposure changes within a frame (frames late p99 <= 1, static_lab 1.5 s) at ``--speed 1``
        and ``max``, but at ``--speed 4`` not in 7 of 24 runs, the single read in all (docs/cameras.md, USB
        transfers).
    transfers : int
        Transfers kept in flight (libusb1) or buffered between reading and decoding (pyusb), 1..64 (default 32
        of libcaer's 8 KiB: a Python host pauses longer than libcaer's C thread; see :data:`.transfers.DEFAULT_TRANSFERS`).
    transfer_size : int, optional
        Bytes per USB bulk transfer, whole 1024-byte packets (default 8 KiB, as libcaer; 256 KiB for
        ``"single"``).
    buffer_s : float
        How far (seconds of sensor time, 0..60; default 0.1, five frames at 50 fps) the consumer may fall
        behind before the reader stops reading and the device drops (and counts) events: a consumer that
        falls behind works on data at most this old, never seconds old.

    Raises
    ------
    ParameterError
        A frame interval, buffer, exposure, batch or transfer size out of its range.
    """

    reconnect: bool = False
    exposure_us: float = 5000.0
    frame_interval_us: float = 20_000.0
    batch_us: int = 1000
    transfer_size: int | None = None
    buffer_s: float = 0.1
    usb: str = "single"
    transfers: int = DEFAULT_TRANSFERS

    def __post_init__(self) -> None:
        fi = self.frame_interval_us
        if not (isinstance(fi, (int, float)) and 2 * READOUT_ALLOWANCE_US <= fi <= P.FRAME_INTERVAL_MAX_US):
            raise ParameterError(
                f"frame interval must be {2 * READOUT_ALLOWANCE_US}..{P.FRAME_INTERVAL_MAX_US} µs, got {fi!r}"
            )
        b = self.buffer_s
        if isinstance(b, bool) or not isinstance(b, (int, float)) or not 0 < b <= 60:
            raise ParameterError(f"buffer_s must be 0..60 seconds of sensor time, got {b!r}")
        for name, value in (
            ("reconnect", bool(self.reconnect)),
            ("exposure_us", check_number("exposure_us", self.exposure_us, 0.0, lo_open=True)),
            ("frame_interval_us", float(fi)),
            ("batch_us", check_number("batch_us", self.batch_us, 1, integer=True)),
            ("buffer_s", float(b)),
        ):
            object.__setattr__(self, name, value)
        if self.usb not in USB_CHOICES + ("single",):
            raise ParameterError(f"usb must be one of {', '.join(USB_CHOICES)}, got {self.usb!r}")
        size = self.transfer_size
        if size is None:
            size = SINGLE_TRANSFER_BYTES if self.usb == "single" else DEFAULT_TRANSFER_BYTES
        n, size = check_transfers(self.transfers, size)
        object.__setattr__(self, "transfer_size", size)


class DavisCamera(CommandedCamera, Source):
    """A DAVIS camera (real or emulated) as a closed-loop source. Build it with :func:`open_camera`.

    Attributes: ``sensor`` (from the device's DVS size registers), ``info`` (serial, firmware, logic
    version, chip, clocks in MHz, ...), ``limits`` (:class:`CameraLimits`), ``state`` ("ready",
    "streaming", "waiting" for a reconnect, "finished", "disconnected", "closed"), ``stats``,
    ``options`` (:class:`CameraOptions`).

    Parameters
    ----------
    device : DavisDevice
        The opened device.
    backend
        The pyusb backend it was found through (used again to find it after a reconnect).
    options : CameraOptions, optional
        How to stream (default: ``CameraOptions()``).

    Raises
    ------
    ParameterError
        ``options`` that is not a :class:`CameraOptions`.
    """

    def __init__(self, device: DavisDevice, backend, options: CameraOptions | None = None):
        options = CameraOptions() if options is None else options
        if not isinstance(options, CameraOptions):
            raise ParameterError(f"DavisCamera takes CameraOptions, got {type(options).__name__}")
        self.options = options
        self.device = device
        self.backend = backend
        self.reconnect = options.reconnect
        self.frame_interval_us = options.frame_interval_us
        self.batch_us = options.batch_us
        #: the USB library the bulk endpoint is read with (``libusb1``, ``pyusb`` or ``single``), the transfers in
        #: flight (or buffered) and their size
        self.usb_library = resolve_usb(options.usb)
        self.transfers = 1 if self.usb_library == "single" else options.transfers
        self.transfer_size = options.transfer_size
        self.buffer_s = options.buffer_s
        w, h = device.dvs_size
        self.sensor = SensorGeometry(int(w), int(h), device.kind)
        self.limits = CameraLimits(
            exposure_min_us=10.0,
            exposure_max_us=float(min(P.EXPOSURE_MAX_US, self.frame_interval_us - READOUT_ALLOWANCE_US)),
            gain_max=DIGITAL_GAIN_MAX,
        )
        self.state = "ready"
        self._lock = threading.RLock()
        self._commands = CommandLog(ECHO_TOLERANCE_CYCLES, ECHO_TOLERANCE_REL)
        self._exposure_us = float(self.limits.clamp(options.exposure_us, 1.0)[0])
        self._last_t = 0
        self._reader: BulkReader | None = None
        self._decoder: DavisDecoder | None = None
        self._iterating = False
        self._closed = False
        self._totals = {
            "transfers": 0,
            "bytes": 0,
            "stalls": 0,
            "timeouts": 0,
            "backpressure_s": 0.0,
            "backpressure_events": 0,
            "queue_peak_bytes": 0,
            "lag_peak_us": 0,
        }
        self._decoded = {}
        self._device_stats: dict = {}  # the device's counters, as last read on this connection
        self._device_totals: dict = {}  # counters of earlier connections (they restart at power-up)
        self.reconnects = 0
        self.info = device.info
        device.send_default_config(self._exposure_us, self.frame_interval_us)
        self._dvs_words: dict[int, int] = {}  # bias words written since (kept for a reconnect)
        self._dvs_filters: tuple | None = None
        self._dvs_applied = None

    # -- source interface -------------------------------------------------------------------------
    cameras = (CAMERA,)

    def packets(self):
        """``(camera, packet)`` pairs (:class:`~necviz.drivers.source.Source`); iterate the camera for bare packets."""
        return route(CAMERA, self)

    def __iter__(self):
        if self._iterating or self._closed:
            raise ParameterError("a DavisCamera can be iterated once (open a new one to read again)")
        self._iterating = True
        try:
            self._start_stream(time_offset_us=0)
            while True:
                item = self._reader.get(0.2)
                if item is None:
                    if self._closed:
                        return
                    continue
                kind, payload = item[0], item[1]
                if kind == "packets":  # decoded on the reader thread
                    cycles = item[4]
                    for pk in payload:
                        yield from self._deliver(pk, cycles)
                elif kind == "finished":
                    for pk in self._decoder.finish():
                        yield from self._deliver(pk)
                    self.state = "finished"
                    return
                elif kind == "disconnected":
                    for pk in self._decoder.finish():  # an exposure cut short still gets its end marker
                        yield from self._deliver(pk)
                    t_s = self._last_t / 1e6
                    self._end_stream(stop_device=False)
                    if not self.reconnect:
                        self.state = "disconnected"
                        raise DeviceDisconnectedError(
                            f"{self.device.kind} {self.device.serial} was unplugged at t={t_s:.3f} s"
                        )
                    if not self._wait_for_device():
                        return
                    self._start_stream(time_offset_us=self._last_t + 1)
                else:
                    self._end_stream(stop_device=True)
                    raise DeviceError(f"{self.device.kind} {self.device.serial}: USB read failed: {payload}")
        finally:
            self.close()

    def set_exposure(
        self, camera: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None:
        """Command exposure (µs, clamped to ``limits``) and digital gain (linear, 1..``limits.gain_max``).

        ``camera`` is ``"camera"`` (the :class:`~necviz.drivers.source.Source` signature).

        Writes APS EXPOSURE = round(exposure_us x ADC MHz) now; ``issue_time_us`` (default: the time of
        the last packet delivered) is the sensor time recorded with the command.
        """
        exp, g = self.limits.clamp(*check_command(camera, exposure_us, gain))
        with self._lock:
            t = self._last_t if issue_time_us is None else int(issue_time_us)
            if not self.device.closed and self.state != "waiting":
                try:
                    cycles = self.device.set_exposure_us(exp)
                except DeviceDisconnectedError:
                    # the command found the unplug before the stream did: the stream reports it (with the
                    # time of its last data) once everything read before it is delivered; with
                    # reconnect the setting is written when the camera returns, as while waiting
                    cycles = self.device.us_to_cycles(exp)
            else:
                cycles = self.device.us_to_cycles(exp)  # written when the device returns
            self._exposure_us = exp
            self._commands.issue(t, exp, g, cycles)

    # -- DVS biases and filters (issue 29) -----------------------------------------------------------
    takes_dvs_biases = True

    @property
    def dvs_family(self) -> str:
        """The bias table the chip uses: ``"DAVIS240"`` or ``"DAVIS346"``."""
        return "DAVIS240" if self.device.kind == "DAVIS240" else "DAVIS346"

    @property
    def dvs_pixel(self):
        """The pixel at libcaer's default biases where it is known: an emulated camera's (its simulator's
        ``DvsParams``); ``None`` for a camera (the bias model then estimates it)."""
        backend = getattr(self.device, "backend", None)
        return getattr(backend, "dvs_base", None) if self.device.emulated else None

    def set_dvs_biases(self, words: dict[int, int]) -> None:
        """Write DVS bias words (module-5 parameter -> word, :mod:`necviz.core.biases`) through the path that
        wrote the defaults (:meth:`~.device.DavisDevice.set_biases`, one 0xC2 request)."""
        with self._lock:
            words = {int(k): int(v) for k, v in words.items()}
            if not self.device.closed and self.state != "waiting":
                self.device.set_biases(words)
            self._dvs_words.update(words)  # written when the device returns, as an exposure
            self._dvs_applied = self._last_t

    def set_dvs_filters(self, background_activity_us: float | None, refractory_us: float | None) -> None:
        """The FPGA's background-activity and refractory filters (µs; ``None`` = off)."""
        with self._lock:
            if not self.device.capabilities.get("dvs_background_activity_filter"):
                raise ParameterError(f"this {self.device.kind}'s logic has no background-activity/refractory filters")
            backend = getattr(self.device, "backend", None)
            if self.device.emulated and not getattr(getattr(backend, "options", None), "fpga_filters", True):
                raise ParameterError(
                    "the emulated camera does not emulate the FPGA's filters unless asked "
                    "(EmulatorOptions(fpga_filters=True)); nothing was written"
                )
            if not self.device.closed and self.state != "waiting":
                self.device.set_dvs_filters(background_activity_us, refractory_us)
            self._dvs_filters = (background_activity_us, refractory_us)

    def dvs_applied_us(self) -> int | None:
        """Stream time from which the last DVS change holds: an emulated device says exactly; for a camera it is
        the time of the last packet delivered when the biases were written (a lower bound: the data already in
        flight, a few ms, was produced before)."""
        backend = getattr(self.device, "backend", None)
        if self.device.emulated and hasattr(backend, "dvs_applied_us"):
            t = backend.dvs_applied_us()
            return None if t is None or self._decoder is None else t + self._stream_offset_us
        return self._dvs_applied

    def _rewrite_dvs(self) -> None:
        if self._dvs_words:
            self.device.set_biases(self._dvs_words)
        if self._dvs_filters is not None:
            self.device.set_dvs_filters(*self._dvs_filters)

    @property
    def camera_info(self) -> CameraInfo:
        """The camera's limits and frame period, and the DAVIS event bus ceiling (its command latency is not known)."""
        return CameraInfo(self.limits, None, known_event_rate_max(self.sensor), self.frame_interval_us)

    def warm_up(self) -> None:
        """Compile or load the stream kernels before the run: a few synthetic words (a clock reset, events, a
        small frame) are encoded and decoded by a throwaway encoder and decoder; an emulated device warms up
        its simulator too. The camera's own state is untouched."""
        from necviz.core.events import EVENT_DTYPE
        from necviz.drivers.davis.encoder import FrameTiming, StreamEncoder

        d = self.device
        enc = StreamEncoder(d.aps_orientation)
        ev = np.zeros(4, EVENT_DTYPE)
        ev["t"] = [10, 11, 40, 90]
        ev["x"], ev["y"], ev["p"] = [1, 2, 3, 4], [1, 1, 2, 3], [1, -1, 1, -1]
        img = np.full((2, 2), 512, np.int64)
        words = np.concatenate(
            [
                enc.timestamp_reset(),
                enc.events(ev),
                enc.frame(FrameTiming(100, 110, 150, 160), img, img, (0, 0, 1, 1), 40),
            ]
        )
        try:  # a warm-up that fails costs latency later, never the run
            DavisDecoder(DecoderOptions(d.dvs_size[0], d.dvs_size[1], aps_width=2, aps_height=2)).decode(
                words.tobytes()
            )
        except NecvizError:
            pass
        d.warm_up()

    def close(self) -> None:
        """Stop the device (documented stop order), join the reader thread, release USB. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._end_stream(stop_device=True)
        self.device.close()
        if self.state not in ("finished", "disconnected"):
            self.state = "closed"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def stats(self) -> dict:
        """Counters of the whole session (all connections):

        * USB: ``transfers``, ``bytes``, ``stalls``, ``timeouts``; ``backpressure_s`` (time the reader
          stopped reading because the consumer was ``buffer_s`` behind) and ``queue_peak_bytes``;
        * decoder: ``events``, ``frames``, ``skipped_words``, ``frames_dropped``, ... ;
        * the device's loss counters (when it has statistics): ``dvs_dropped_on_stall`` (DVS events
          the device dropped because the host did not read), ``extinput_dropped_on_stall``,
          ``dvs_dropped``; ``dropped_events`` is their DVS total — events lost, never silently;
        * ``commands_issued``, ``reconnects``.
        """
        out = dict(self._totals)
        if self._reader is not None:
            for k, v in self._reader.stats.items():
                out[k] = max(out.get(k, 0), v) if k in _PEAKS else out.get(k, 0) + v
        dec = dict(self._decoded)
        if self._decoder is not None:
            for k, v in self._decoder.stats.items():
                dec[k] = dec.get(k, 0) + v
        out.update(dec)
        for k in ("events", "frames", "skipped_words"):
            out.setdefault(k, 0)
        self._read_device_stats()
        dev = dict(self._device_totals)
        for k, v in self._device_stats.items():
            dev[k] = dev.get(k, 0) + v
        out.update(dev)
        out["dropped_events"] = int(dev.get("dvs_dropped_on_stall", 0) + dev.get("dvs_dropped", 0))
        out["commands_issued"] = self.commands_issued
        out["reconnects"] = self.reconnects
        return out

    def _read_device_stats(self) -> None:
        """Refresh the device's counters (kept as last read if the device is gone)."""
        if not self.device.closed and self.state not in ("waiting", "disconnected"):
            try:
                self._device_stats = self.device.statistics()
            except DeviceError:
                pass

    @property
    def usb_transfers(self) -> dict:
        """How the bulk endpoint is read: ``{"library", "transfers", "transfer_bytes"}`` (``live --json``)."""
        return {"library": self.usb_library, "transfers": self.transfers, "transfer_bytes": self.transfer_size}

    @property
    def exposure_us(self) -> float:
        """The last commanded exposure (µs)."""
        return self._exposure_us

    # -- streaming ----------------------------------------------------------------------------------
    def _start_stream(self, time_offset_us: int) -> None:
        d = self.device
        fmt = DecoderOptions(
            d.dvs_size[0],
            d.dvs_size[1],
            aps_width=d.aps_size[0],
            aps_height=d.aps_size[1],
            dvs_invert_xy=bool(d.dvs_orientation & 4),
            aps_orientation=d.aps_orientation,
            imu_orientation=d.imu_orientation,
            imu_model=d.imu_type,
            adc_shift=1 if d.kind == "DAVIS240" else 0,
            color_filter=d.aps_color_filter if d.aps_color_filter in COLOR_FILTERS else 0,
        )
        self._decoder = DavisDecoder(fmt, time_offset_us=time_offset_us)
        self._stream_offset_us = time_offset_us
        self._reader = make_reader(
            d, self.usb_library, self.transfers, self.transfer_size, buffer_s=self.buffer_s, decode=self._decode
        )
        d.start()
        self._reader.start()
        self.state = "streaming"

    def _end_stream(self, stop_device: bool) -> None:
        """Stop the reader (and the device) and fold the counters of this connection into the totals."""
        if self._reader is not None:
            if stop_device:
                try:
                    self.device.stop()
                except DeviceError:
                    pass
            self._reader.stop()
            for k, v in self._reader.stats.items():
                self._totals[k] = max(self._totals.get(k, 0), v) if k in _PEAKS else self._totals.get(k, 0) + v
            self._reader = None
            self._read_device_stats()  # the last counts of this connection (a replugged device restarts them)
            for k, v in self._device_stats.items():
                self._device_totals[k] = self._device_totals.get(k, 0) + v
            self._device_stats = {}
        if self._decoder is not None:
            for k, v in self._decoder.stats.items():
                self._decoded[k] = self._decoded.get(k, 0) + v
            self._decoder = None

    def _wait_for_device(self) -> bool:
        """Poll discovery every 0.5 s until the same serial returns; reopen it. False if closed meanwhile."""
        self.state = "waiting"
        serial = self.device.serial
        self.device.close()
        while not self._closed:
            time.sleep(RECONNECT_POLL_S)
            try:
                dev = open_device(self.backend, serial, self.device.emulated)
            except DeviceNotFoundError:
                continue
            except DeviceError:
                continue
            with self._lock:
                self.device = dev
                dev.send_default_config(self._exposure_us, self.frame_interval_us)
                self._rewrite_dvs()  # the biases and filters set during the run, again
                self.reconnects += 1
            return True
        return False

    def _decode(self, data) -> tuple:
        """One transfer decoded (on the reader thread): its packets, the sensor time reached and the exposure
        cycles each of its frames reported (by frame sequence number)."""
        dec = self._decoder
        packets = dec.decode(data)
        cycles = {pk.sequence: dec.frame_cycles.get(pk.sequence, -1) for pk in packets if isinstance(pk, Frame)}
        return packets, dec.time_us, cycles

    # -- packets --------------------------------------------------------------------------------------
    def _deliver(self, pk, cycles=None):
        if isinstance(pk, np.ndarray):
            if pk.size == 0:
                return
            self._last_t = int(pk["t"][-1])
            t = pk["t"]
            b = self.batch_us
            if (int(t[0]) // b) == (int(t[-1]) // b):
                yield EventBatch(pk)
                return
            edges = np.arange((int(t[0]) // b + 1) * b, int(t[-1]) + 1, b)
            cuts = np.searchsorted(t, edges, side="left")
            prev = 0
            for c in cuts.tolist() + [pk.size]:
                if c > prev:
                    yield EventBatch(pk[prev:c])
                    prev = c
            return
        if isinstance(pk, Frame):
            pk = self._apply_command(pk, -1 if cycles is None else cycles.get(pk.sequence, -1))
            self._last_t = max(self._last_t, int(pk.exposure_end_us))
        elif isinstance(pk, ExposureMarker):
            self._last_t = max(self._last_t, int(pk.t_us))
        yield pk

    def _apply_command(self, frame: Frame, cyc: int) -> Frame:
        """Mark the command this frame was exposed with (it reported ``cyc`` ADC cycles, -1: none) as applied;
        apply its digital gain."""
        return with_gain(frame, self._commands.frame(int(frame.exposure_start_us), None if cyc < 0 else cyc))


def open_camera(
    device: str = "usb",
    serial: str | None = None,
    *,
    options: CameraOptions | None = None,
    emulator: EmulatorOptions | None = None,
    faults: Faults | None = None,
    backend=None,
) -> DavisCamera:
    """Open a DAVIS camera: ``device="usb"`` (hardware through libusb) or ``"emulated"``.

    The device is configured (default biases, ``options.exposure_us``, ``options.frame_interval_us``)
    but streams only once iterated.

    Parameters
    ----------
    device : str
        ``"usb"`` or ``"emulated"``.
    serial : str, optional
        The camera's serial number (default: the first one found).
    options : CameraOptions, optional
        How to stream (default: ``CameraOptions()``).
    emulator : EmulatorOptions, optional
        For ``"emulated"`` without ``backend``: the virtual camera's scene, pacing and identity.
    faults : Faults, optional
        For ``"emulated"`` without ``backend``: faults the virtual camera injects.
    backend : optional
        An existing :class:`~.emulator.EmulatedDavis346` (or any pyusb backend) to open the camera on.

    Returns
    -------
    DavisCamera

    Raises
    ------
    ParameterError
        An unknown ``device``, or options out of range.
    DeviceNotFoundError
        No camera attached, or none with ``serial``.
    DeviceError
        Version mismatch, permission denied, ...
    """
    if device not in ("usb", "emulated"):
        raise ParameterError(f"device must be 'usb' or 'emulated', got {device!r}")
    emulated = device == "emulated"
    if backend is None:
        if emulated:
            from necviz.drivers.davis.emulator import EmulatedDavis346

            backend = EmulatedDavis346(emulator, faults)
        else:
            backend = usb_backend()
    dev = open_device(backend, serial, emulated)
    try:
        return DavisCamera(dev, backend, options)
    except BaseException:
        dev.close()
        raise
