"""A virtual DAVIS346 behind a pyusb backend: the whole driver path runs with no hardware.

``usb.core.find(idVendor=0x152A, backend=EmulatedDavis346())`` finds one DAVIS FX3 device (PID
0x841A). The backend answers what the driver asks of a real camera:

* descriptors (device with ``bcdDevice & 0xFF`` = firmware, configuration 1, interface 0 with the
  interrupt endpoint 0x81 and the bulk endpoint 0x82) and the serial-number string;
* vendor requests 0xBF (read/write one register) and 0xC2 (write several) on a register file
  holding the logic-18 map of :mod:`.protocol` (sizes, clocks, versions; every write is stored and
  logged in :attr:`EmulatedDavis346.transfers`, in order, so a test can check the start sequence);
* bulk reads of endpoint 0x82 returning 16-bit words (:mod:`.encoder`) of a closed-loop simulated
  scene (:class:`~necviz.drivers.sim.rig.SimRig`, one camera). Data flows only while the
  producers, MUX, timestamps and USB run registers are on, as on the device. The APS EXPOSURE
  register (ADC cycles) is honoured: a write becomes ``set_exposure(cycles / adc_mhz)`` on the
  simulator, which applies it at the next exposure starting at least 1 ms later; each frame carries
  the cycles it was exposed with (misc10 words), its reset read is the constant 1023 and its signal
  read ``1023 - (4 Z + 1)``, so the driver decodes exactly the simulator's 8-bit image. One IMU
  sample (1 g along -y, 30 °C, no rotation) is sent per millisecond while the IMU runs.

Frame geometry and timing come from the registers when streaming starts: the APS ROI, and
``FRAME_INTERVAL`` (the simulator's readout takes 1 ms, so exposures are limited to the interval
minus 1 ms). Device time 0 is the simulator time at which streaming (re)started or the timestamps
were reset; a timestamp-reset word opens the stream.

End of data: when the scenario is over, bulk reads time out with no data and
:attr:`EmulatedDavis346.stream_finished` becomes True — the driver checks it (through the backend)
to end iteration cleanly. A real camera never finishes.

Fault injection (:class:`Faults`): the device disappears once the stream reaches ``unplug_after_s``
(bulk reads and control transfers fail with ENODEV, discovery no longer lists it; with
``replug_after_s`` it comes back that many wall-clock seconds later, power-cycled: registers reset,
timestamps restart at 0, the scene continues); the bulk endpoint stalls once at ``stall_after_s``
(EPIPE until ``clear_halt``); ``firmware``/``logic`` set the reported versions; ``permission_denied``
makes opening fail with EACCES as libusb does without the udev rule.

Pacing (``realtime``, ``time_scale``), the device FIFO and what it drops, transfers in flight and the
``extra_event_rate`` load generator are described in :mod:`.emulator_stream`.

The backend is assembled from three modules: this one, the device model (register file, power-up,
plug state, :class:`Faults`); :mod:`.emulator_usb`, the USB surface (enumeration, descriptors,
handles, control transfers, :class:`ControlRecord`); and :mod:`.emulator_stream`, the data path
(simulated sensor → words → device FIFO → bulk transfers). Their public names are importable from here.
"""

from __future__ import annotations

import errno
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import usb.backend
import usb.core

from necviz.core.errors import ParameterError
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.emulator_stream import EARLY_PACKET_US, FIFO_BYTES, DataPathMixin
from necviz.drivers.davis.emulator_usb import ControlRecord, UsbInterfaceMixin, _usb_error
from necviz.drivers.davis.encoder import StreamLayout

#: clocks the emulated DAVIS346 reports: logic, ADC, USB (MHz) and the deviation (x1000)
EMULATED_CLOCKS = (104, 30, 80, 1008)
EMULATED_SERIAL = "EMU00346"
#: control transfers kept in :attr:`EmulatedDavis346.transfers` (the oldest are forgotten)
TRANSFER_LOG = 65536


@dataclass
class Faults:
    """Faults to inject. Times ``*_after_s`` are stream seconds (device time since streaming started),
    except ``replug_after_s``: wall-clock seconds between the unplug and the device's return."""

    unplug_after_s: float | None = None
    replug_after_s: float | None = None
    stall_after_s: float | None = None
    firmware: int = 6
    logic: int = 18
    logic_patch: int = 1
    permission_denied: bool = False


@dataclass(frozen=True)
class CameraVariant:
    """What differs between real DAVIS cameras and their logic, for the emulator to present (the driver reads
    every one of these from the device's registers or its word stream, as libcaer does).

    Parameters
    ----------
    chip_id : int
        SYSINFO CHIP_IDENTIFIER (:data:`~.protocol.CHIP_NAMES`; default 5, DAVIS346B). A DAVIS240 id makes the
        driver write the DAVIS240 bias table.
    dvs_orientation : int
        DVS ORIENTATION_INFO (bit 2: X/Y inverted, the row words carry x; the size registers then report the
        sensor's width as its row count). The APS orientation is :attr:`EmulatorOptions.aps_orientation`.
    layout : StreamLayout
        Where the frame header words go (after or before the frame start) and whether the exposure specials
        are sent.
    echo_offset_cycles : int
        Added to the exposure each frame reports (an echo that differs from the register by a cycle or two).
    color_filter : int
        APS COLOR_FILTER (0 mono; 1..4 Bayer RGBG, GRGB, GBGR, BGRG; 5..8 RGBW variants). The emulated scene is
        neutral grey, so the mosaic it sends is the grey image itself; the driver demosaics it as libcaer does.

    Raises
    ------
    ParameterError
        An unknown chip identifier.
    """

    chip_id: int = 5
    dvs_orientation: int = 0
    layout: StreamLayout = StreamLayout()
    echo_offset_cycles: int = 0
    color_filter: int = 0

    def __post_init__(self) -> None:
        if self.chip_id not in P.CHIP_NAMES:
            raise ParameterError(f"unknown DAVIS chip identifier {self.chip_id!r}; known: {sorted(P.CHIP_NAMES)}")
        object.__setattr__(self, "dvs_orientation", int(self.dvs_orientation) & 4)
        object.__setattr__(self, "echo_offset_cycles", int(self.echo_offset_cycles))
        if self.color_filter not in range(9):
            raise ParameterError(f"APS colour filter must be 0..8, got {self.color_filter!r}")


@dataclass(frozen=True)
class EmulatorOptions:
    """Settings of the virtual DAVIS346: its scene, its pacing and its identity (validated here, once).

    Parameters
    ----------
    scenario : str
        The simulator scene (:func:`~necviz.drivers.sim.scenes.make_scenario`), a name in
        :data:`~necviz.drivers.sim.scenes.SCENARIOS`.
    seed : int
        The scene's seed (also seeds the ``extra_event_rate`` load generator).
    duration_s : float, optional
        Seconds of scene; ``None`` uses the scenario's default length.
    scenario_params : dict, optional
        Extra keyword parameters of the scenario (kept as a copy).
    realtime : bool
        Pace the stream to the wall clock.
    time_scale : float
        Wall-clock seconds per stream second when ``realtime`` (:mod:`.emulator_stream`).
    fifo_bytes : int
        Size of the device FIFO (:mod:`.emulator_stream`).
    extra_event_rate : float
        Load generator: extra DVS events per second on top of the scene's (0..1e9).
    sensor : SensorGeometry
        Array size (default DAVIS346 346 x 260; tests use a smaller one to run faster — the size
        registers report it).
    serial : str
        Serial-number string (at most 8 characters).
    aps_orientation : int
        Value of the APS ORIENTATION_INFO register (readout order of frames; the low 3 bits).
    variant : CameraVariant
        The chip and the stream layout the camera presents (default: a DAVIS346B as the FPGA source
        describes it).
    fpga_filters : bool
        Emulate the FPGA's background-activity and refractory filters as their registers say
        (:mod:`.emulator_filters`); off by default, so the stream stays the simulator's events.
    bus, address : int
        Where pyusb reports the device.

    Raises
    ------
    ParameterError
        An unknown scenario, a duration that is not a positive number, a serial number longer
        than 8 characters, a ``time_scale`` or ``fifo_bytes`` that is not a positive number, or an
        ``extra_event_rate`` outside 0..1e9 events/s.
    """

    scenario: str = "tunnel_exit"
    seed: int = 0
    duration_s: float | None = None
    scenario_params: dict | None = None
    realtime: bool = False
    time_scale: float = 1.0
    fifo_bytes: int = FIFO_BYTES
    extra_event_rate: float = 0.0
    sensor: SensorGeometry = DAVIS346
    serial: str = EMULATED_SERIAL
    aps_orientation: int = 0
    variant: CameraVariant = CameraVariant()
    fpga_filters: bool = False
    bus: int = 0
    address: int = 1

    def __post_init__(self) -> None:
        from necviz.drivers.sim.scenes import SCENARIOS

        if self.scenario not in SCENARIOS:
            raise ParameterError(f"unknown scenario {self.scenario!r}; known: {', '.join(sorted(SCENARIOS))}")
        d = self.duration_s
        if d is not None and not (isinstance(d, (int, float)) and d > 0):
            raise ParameterError(f"duration must be a positive number of seconds, got {d!r}")
        if len(self.serial) > 8:
            raise ParameterError("a DAVIS serial number has at most 8 characters")
        for label in ("time_scale", "fifo_bytes"):
            v = getattr(self, label)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or v != v or v == float("inf"):
                raise ParameterError(f"{label} must be a positive number, got {v!r}")
        rate = self.extra_event_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 <= rate < 1e9:
            raise ParameterError(f"extra_event_rate must be 0..1e9 events/s, got {rate!r}")
        for name, value in (
            ("seed", int(self.seed)),
            ("scenario_params", dict(self.scenario_params or {})),
            ("realtime", bool(self.realtime)),
            ("time_scale", float(self.time_scale)),
            ("fifo_bytes", int(self.fifo_bytes)),
            ("extra_event_rate", float(rate)),
            ("aps_orientation", int(self.aps_orientation) & 7),
        ):
            object.__setattr__(self, name, value)


class EmulatedDavis346(UsbInterfaceMixin, DataPathMixin, usb.backend.IBackend):
    """pyusb backend with one virtual DAVIS346 (see the module docstring).

    Parameters
    ----------
    options : EmulatorOptions, optional
        The scene, pacing and identity of the device (default: ``EmulatorOptions()``); its fields
        are also readable as attributes of the backend (``scenario``, ``sensor``, ``serial`` ...).
    faults : Faults, optional
        Faults to inject (default none).

    Raises
    ------
    ParameterError
        ``options`` that is not an :class:`EmulatorOptions`.
    """

    def __init__(self, options: EmulatorOptions | None = None, faults: Faults | None = None):
        super().__init__()
        options = EmulatorOptions() if options is None else options
        if not isinstance(options, EmulatorOptions):
            raise ParameterError(f"EmulatedDavis346 takes EmulatorOptions, got {type(options).__name__}")
        self.options = options
        o = options
        self.scenario, self.seed, self.duration_s = o.scenario, o.seed, o.duration_s
        self.scenario_params = dict(o.scenario_params or {})
        self.faults = faults or Faults()
        self.realtime = o.realtime
        self.time_scale = o.time_scale
        self.fifo_bytes = o.fifo_bytes
        #: room of the host's transfers submitted and waiting behind the one being read (bytes; see emulator_stream)
        self.host_buffer_bytes = 0
        self.extra_event_rate = o.extra_event_rate
        self._load_rng = np.random.default_rng([self.seed, 346])
        self.sensor = o.sensor
        self.serial = o.serial
        self.aps_orientation = o.aps_orientation
        self.variant = o.variant
        self.bus, self.address = o.bus, o.address
        self.lock = threading.RLock()  # registers and faults (the control path; the data path takes it only to check)
        # the data path (simulator, encoder, FIFO): never held by an exposure write, so a control transfer does not
        # wait for the simulation (taken after ``lock`` when both are needed, never the other way round)
        self._data_lock = threading.Lock()
        #: the last TRANSFER_LOG control transfers, in order (``transfers_total`` counts them all)
        self.transfers: deque[ControlRecord] = deque(maxlen=TRANSFER_LOG)
        self.transfers_total = 0
        self.bulk_reads = 0
        self.stalls = 0
        self.stream_finished = False
        self.plugged = True
        self._unplugged_at: float | None = None
        self._stalled_once = False
        self._halted = False
        self._rig = None
        self._gen = None
        self._scene_done = False
        self._filters = None
        if o.fpga_filters:
            from necviz.drivers.davis.emulator_filters import FpgaFilters

            self._filters = FpgaFilters(self.sensor.width, self.sensor.height)
        self._power_on()

    # -- device state -------------------------------------------------------------------------------
    def _power_on(self) -> None:
        """Register file after power-up; streaming state cleared."""
        w, h = self.sensor.width, self.sensor.height
        logic, adc, usb_clk, dev = EMULATED_CLOCKS
        f = self.faults
        self.regs: dict[tuple[int, int], int] = {
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_VERSION): f.logic,
            (P.SYSINFO.MODULE, P.SYSINFO.CHIP_IDENTIFIER): self.variant.chip_id,
            (P.SYSINFO.MODULE, P.SYSINFO.DEVICE_IS_MASTER): 1,
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_CLOCK): logic,
            (P.SYSINFO.MODULE, P.SYSINFO.ADC_CLOCK): adc,
            (P.SYSINFO.MODULE, P.SYSINFO.USB_CLOCK): usb_clk,
            (P.SYSINFO.MODULE, P.SYSINFO.CLOCK_DEVIATION): dev,
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_PATCH): f.logic_patch,
            # size registers count the chip's columns and rows: swapped from the output size when X/Y are inverted
            (P.DVS.MODULE, P.DVS.SIZE_COLUMNS): h if self.variant.dvs_orientation & 4 else w,
            (P.DVS.MODULE, P.DVS.SIZE_ROWS): w if self.variant.dvs_orientation & 4 else h,
            (P.DVS.MODULE, P.DVS.ORIENTATION_INFO): self.variant.dvs_orientation,
            (P.APS.MODULE, P.APS.SIZE_COLUMNS): h if self.aps_orientation & 4 else w,
            (P.APS.MODULE, P.APS.SIZE_ROWS): w if self.aps_orientation & 4 else h,
            (P.APS.MODULE, P.APS.ORIENTATION_INFO): self.aps_orientation,
            (P.APS.MODULE, P.APS.COLOR_FILTER): self.variant.color_filter,
            (P.APS.MODULE, P.APS.HAS_GLOBAL_SHUTTER): 1,
            (P.APS.MODULE, P.APS.GLOBAL_SHUTTER): 1,
            (P.APS.MODULE, P.APS.START_COLUMN_0): 0,
            (P.APS.MODULE, P.APS.START_ROW_0): 0,
            (P.APS.MODULE, P.APS.END_COLUMN_0): w - 1,
            (P.APS.MODULE, P.APS.END_ROW_0): h - 1,
            (P.APS.MODULE, P.APS.EXPOSURE): round(4000 * self.adc_mhz),
            (P.APS.MODULE, P.APS.FRAME_INTERVAL): round(40000 * self.adc_mhz),
            (P.IMU.MODULE, P.IMU.TYPE): 1,
            (P.IMU.MODULE, P.IMU.ORIENTATION_INFO): 0,
            (P.MUX.MODULE, P.MUX.HAS_STATISTICS): 1,
            (P.DVS.MODULE, P.DVS.HAS_STATISTICS): 1,
            (P.DVS.MODULE, P.DVS.HAS_PIXEL_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_BACKGROUND_ACTIVITY_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_ROI_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_SKIP_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_POLARITY_FILTER): 1,
            (P.EXTINPUT.MODULE, P.EXTINPUT.HAS_GENERATOR): 1,
        }
        self._streaming = False
        self._encoder = None
        self._pending = bytearray()  # the device FIFO
        self.dvs_dropped = 0  # MUX STAT_DVS_DROPPED: DVS events dropped because the FIFO was full
        self.events_generated = 0  # DVS events the sensor produced (delivered + dropped)
        self.frames_skipped = 0  # frames not exposed because the FIFO was full at their start
        self.fifo_peak = 0
        self.clock_slip_us = 0  # realtime: device time lost because the simulation fell behind the wall clock
        self._load_us = 0  # device time up to which load events were generated
        self._read_end_us: float | None = None  # device time the last transfer ended (realtime)
        self._unbounded = False
        self._late = 0  # bytes at the FIFO's head produced late for an earlier transfer
        self._base_us = 0  # simulator time of device time 0
        self._frame_open = False
        self._next_imu_us = 0
        self._wall_start = None
        self._halted = False

    @property
    def _adc_shift(self) -> int:
        """The decoder doubles a DAVIS240's samples (libcaer's ``davisCommonEventTranslator``): encode half."""
        return 1 if self.variant.chip_id in P.DAVIS240_CHIPS else 0

    @property
    def adc_mhz(self) -> float:
        return EMULATED_CLOCKS[1] * EMULATED_CLOCKS[3] / 1000.0

    # -- DVS biases: the emulated pixel follows them ---------------------------------------------------
    @property
    def dvs_family(self) -> str:
        return "DAVIS240" if self.variant.chip_id in P.DAVIS240_CHIPS else "DAVIS346"

    @property
    def _dvs_bias_params(self) -> tuple[int, ...]:
        from necviz.core.biases import BIAS_ADDRESSES, DVS_BIAS_NAMES

        return tuple(BIAS_ADDRESSES[self.dvs_family][n] for n in DVS_BIAS_NAMES)

    @property
    def dvs_base(self):
        """The emulated pixel at libcaer's default biases: the simulated DAVIS346 (``DvsParams()``)."""
        from necviz.drivers.sim.dvs import DvsParams

        return DvsParams()

    def _dvs_params(self):
        """The simulator's pixel at the bias words in the registers (the simulated DAVIS346 at libcaer's defaults,
        scaled by the bias model: :func:`~necviz.drivers.sim.dvs.params_for_biases`)."""
        from necviz.core.biases import DvsBiases
        from necviz.drivers.sim.dvs import params_for_biases

        words = {p: v for (m, p), v in self.regs.items() if m == P.BIAS.MODULE}
        fam = self.dvs_family
        return params_for_biases(self.dvs_base, DvsBiases.from_words(words, fam), fam)

    def _ensure_rig(self) -> None:
        new = self._rig is None
        if self._encoder is None and self._filters is not None:  # streaming (re)starts: the filters' memory too
            self._filters.reset()
        super()._ensure_rig()
        if new and self._rig is not None:  # before its first packet: the run's pixel
            self._rig.set_dvs_params(self._dvs_params())

    def _put_events(self, ev: np.ndarray) -> None:
        if self._filters is not None and ev.size:
            D = P.DVS
            ba = self.reg(D.MODULE, D.FILTER_BACKGROUND_ACTIVITY) * self.reg(
                D.MODULE, D.FILTER_BACKGROUND_ACTIVITY_TIME
            )
            refr = self.reg(D.MODULE, D.FILTER_REFRACTORY_PERIOD) * self.reg(D.MODULE, D.FILTER_REFRACTORY_PERIOD_TIME)
            ev = self._filters.apply(ev, 250 * ba, 250 * refr)
            if ev.size == 0:
                return
        super()._put_events(ev)

    def dvs_applied_us(self) -> int | None:
        """Device time from which the last bias change holds in the emitted events (``None``: none while streaming)."""
        rig = self._rig
        t = None if rig is None else rig.dvs_applied_us()
        return None if t is None else max(0, int(t) - int(self._base_us))

    def reg(self, module: int, param: int) -> int:
        """Current value of a register (0 if never written)."""
        return self.regs.get((module, param), 0)

    def _log(self, record: ControlRecord) -> None:
        self.transfers.append(record)
        self.transfers_total += 1

    def writes(self) -> list[tuple[int, int, int]]:
        """Every register write received (of the last TRANSFER_LOG transfers), in order: ``(module, param, value)``."""
        return [(r.module, r.param, r.value) for r in self.transfers if r.direction == "out"]

    def _running(self) -> bool:
        r = self.reg
        return bool(
            r(P.MUX.MODULE, P.MUX.RUN)
            and r(P.MUX.MODULE, P.MUX.TIMESTAMP_RUN)
            and r(P.USB.MODULE, P.USB.RUN)
            and r(P.MUX.MODULE, P.MUX.RUN_CHIP)
        )

    def _check_plug(self) -> None:
        """Raise ENODEV while unplugged; come back (power-cycled) after ``replug_after_s``."""
        if self.plugged:
            return
        f = self.faults
        if f.replug_after_s is not None and time.monotonic() - self._unplugged_at >= f.replug_after_s:
            self.plugged = True
            self.faults = Faults(**{**f.__dict__, "unplug_after_s": None})  # unplug once
            self._power_on()
            return
        raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")

    def unplug(self) -> None:
        """Pull the cable now."""
        with self.lock:
            self.plugged = False
            self._unplugged_at = time.monotonic()

    #: tests: the next :meth:`open_libusb1` handle fires up to this many callbacks in reverse order, and completes
    #: the transfers submitted under these numbers with these statuses (:mod:`.emulator_libusb1`)
    libusb1_reorder = 1
    libusb1_inject: dict[int, int] = {}

    def open_libusb1(self):
        """``(context, handle)``: stand-ins for the ``libusb1`` package's, served by this device
        (:mod:`.emulator_libusb1`), so the driver's asynchronous-transfer path runs without the package or a
        camera; the handle is kept as ``libusb1_handle``."""
        from necviz.drivers.davis.emulator_libusb1 import EmulatedContext, EmulatedHandle

        with self.lock:
            self._check_plug()
        handle = EmulatedHandle(self, self.libusb1_reorder, self.libusb1_inject)
        self.libusb1_handle = handle
        return EmulatedContext(handle), handle

    # -- register file (what the control transfers of emulator_usb read and write) ------------------
    def _read(self, module: int, param: int) -> int:
        if module == P.MUX.MODULE and param in (P.MUX.STAT_DVS_DROPPED, P.MUX.STAT_DVS_DROPPED + 1):
            v = self.dvs_dropped  # 64-bit counter: MSB word, then LSB word
            return (v >> 32) & 0xFFFFFFFF if param == P.MUX.STAT_DVS_DROPPED else v & 0xFFFFFFFF
        if module == P.DVS.MODULE and param in (89, 90, 91, 92) and self._filters is not None:
            v = int(self._filters.counts[0 if param < 91 else 1])  # FILTERED_BA, FILTERED_REFRACTORY (64-bit)
            return (v >> 32) & 0xFFFFFFFF if param in (89, 91) else v & 0xFFFFFFFF
        if module in (P.MUX.MODULE, P.DVS.MODULE) and 81 <= param <= 92:
            return 0  # the other statistics counters: nothing dropped or filtered
        return self.reg(module, param)

    def _write(self, request: int, module: int, param: int, value: int) -> None:
        self._log(ControlRecord("out", request, module, param, value, time.monotonic()))
        key = (module, param)
        if module == P.SYSINFO.MODULE or key in (
            (P.DVS.MODULE, P.DVS.SIZE_COLUMNS),
            (P.DVS.MODULE, P.DVS.SIZE_ROWS),
            (P.APS.MODULE, P.APS.SIZE_COLUMNS),
            (P.APS.MODULE, P.APS.SIZE_ROWS),
        ):
            return  # read-only
        self.regs[key] = value
        if key == (P.APS.MODULE, P.APS.EXPOSURE) and self._rig is not None:
            us = max(value / self.adc_mhz, 1.0)
            self._rig.set_exposure("camera", us, 1.0)
        elif module == P.BIAS.MODULE and param in self._dvs_bias_params and self._rig is not None:
            self._rig.set_dvs_params(self._dvs_params())  # the pixel follows its biases (issue 29)
        elif key == (P.MUX.MODULE, P.MUX.TIMESTAMP_RESET) and value and self._encoder is not None:
            with self._data_lock:  # the FIFO and device time belong to the data path (lock order: lock, data lock)
                self._pending += self._encoder.timestamp_reset().tobytes()
                self._base_us = self._rig.now_us if self._rig is not None else 0


def find_emulated(backend: EmulatedDavis346):
    """The emulated device as a ``usb.core.Device`` (None while unplugged)."""
    return usb.core.find(idVendor=P.VID, idProduct=P.PID_FX3, backend=backend)


__all__ = [
    "CameraVariant",
    "EmulatedDavis346",
    "EmulatorOptions",
    "Faults",
    "ControlRecord",
    "EMULATED_CLOCKS",
    "EMULATED_SERIAL",
    "find_emulated",
    "FIFO_BYTES",
    "EARLY_PACKET_US",
    "TRANSFER_LOG",
]
