"""A virtual DAVIS346 behind a pyusb backend: the whole driver path runs with no hardware.

``usb.core.find(idVendor=0x152A, backend=EmulatedDavis346())`` finds one DAVIS FX3 device (PID
0x841A). The backend answers what the driver asks of a real camera:

* descriptors (device with ``bcdDevice & 0xFF`` = firmware, configuration 1, interface 0 with the
  interrupt endpoint 0x81 and the bulk endpoint 0x82) and the serial-number string;
* vendor requests 0xBF (read/write one register) and 0xC2 (write several) on a register file
  holding the logic-18 map of :mod:`.protocol` (sizes, clocks, versions; every write is stored and
  logged in :attr:`EmulatedDavis346.transfers`, in order, so a test can check the start sequence);
* bulk reads of endpoint 0x82 returning 16-bit words (:mod:`.encoder`) of a closed-loop simulated
  scene (:class:`~necviz.drivers.sim.camera.SimRig`, one camera). Data flows only while the
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

Pacing: ``realtime=False`` produces data as fast as it is read (nothing can be lost: the device
waits for the host). ``realtime=True`` runs the sensor on the wall clock (device time = wall time
since streaming started x ``time_scale``; a scale below 1 slows the device so tests can emulate full
rate on a small machine) and models the device's buffering:

* **Transfers in flight.** While the host is inside a bulk read, data flows into its buffer; the
  transfer ends when the buffer is full or, holding data, 1 ms of device time after it started
  (the early-packet timer: the FX3 sends a short packet).
* **Device FIFO.** Between transfers (the host not reading: a busy reader thread, a full host
  queue) data waits in the device, which holds ``fifo_bytes`` (default :data:`FIFO_BYTES` =
  128 KiB: the FPGA's event FIFOs plus the FX3's DMA buffers, an assumption — the FX3 has 512 KiB
  of SRAM in all, shared with its firmware; that is about 2 ms at the DAVIS346's peak of roughly
  70 MB/s). When it is full, DVS events are dropped whole and counted, as the device does with
  ``DROP_DVS_ON_TRANSFER_STALL`` on; the count is what the MUX statistics register
  ``STAT_DVS_DROPPED`` reports (the driver reads it). APS frames wait rather than drop
  (``WAIT_ON_TRANSFER_STALL``): a frame that would start while the FIFO is full is not exposed at
  all (counted in :attr:`EmulatedDavis346.frames_skipped`); timestamps, IMU samples and the words of
  a frame already started are never dropped, so the FIFO may exceed its size by about one frame.

``extra_event_rate`` (events/s of device time) adds uniformly random DVS events to the scene's, a
load generator for full-rate tests; :attr:`EmulatedDavis346.events_generated` counts every DVS
event the sensor produced, :attr:`EmulatedDavis346.dvs_dropped` those the FIFO dropped.
"""

from __future__ import annotations

import array
import errno
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import usb.backend
import usb.core

from ...core.errors import ParameterError
from ...core.events import EVENT_DTYPE
from ...core.frames import ExposureMarker, Frame
from ...core.sensor import DAVIS346, SensorGeometry
from . import protocol as P
from .encoder import EXPOSURE_END, EXPOSURE_START, FRAME_END, StreamEncoder, cds_pair

#: clocks the emulated DAVIS346 reports: logic, ADC, USB (MHz) and the deviation (x1000)
EMULATED_CLOCKS = (104, 30, 80, 1008)
EMULATED_SERIAL = "EMU00346"
#: device-side buffering assumed for the DAVIS346 FX3 (bytes; see the module docstring)
FIFO_BYTES = 128 * 1024
#: the early-packet timer: a transfer holding data ends this long after it started (device µs)
EARLY_PACKET_US = 1000
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
class ControlRecord:
    """One control transfer the emulator received (0xC2 requests give one record per entry).

    ``direction`` is "out" (register write), "in" (register read) or "clear_halt" (``param`` = the
    endpoint); ``t_s`` is ``time.monotonic()`` when it arrived.
    """

    direction: str
    request: int
    module: int
    param: int
    value: int
    t_s: float = 0.0


class _Desc:
    """A descriptor: plain attributes, as pyusb reads them."""

    def __init__(self, **kw):
        self.extra_descriptors = []
        self.__dict__.update(kw)


class _Handle:
    def __init__(self, dev):
        self.dev = dev


def _usb_error(err: int, text: str) -> usb.core.USBError:
    return usb.core.USBError(text, error_code=None, errno=err)


class EmulatedDavis346(usb.backend.IBackend):
    """pyusb backend with one virtual DAVIS346 (see the module docstring).

    Parameters
    ----------
    scenario, seed, duration_s : the simulator scene (:func:`~necviz.drivers.sim.scenes.make_scenario`);
        ``duration_s`` None uses the scenario's default length.
    faults : :class:`Faults` to inject (default none).
    realtime : pace the stream to the wall clock.
    sensor : array size (default DAVIS346 346 x 260; tests use a smaller one to run faster — the size
        registers report it).
    serial : serial-number string (at most 8 characters).
    aps_orientation : value of the APS ORIENTATION_INFO register (readout order of frames).
    scenario_params : extra keyword parameters of the scenario.
    """

    def __init__(self, scenario: str = "tunnel_exit", seed: int = 0, duration_s: float | None = None,
                 faults: Faults | None = None, realtime: bool = False, *, sensor: SensorGeometry = DAVIS346,
                 serial: str = EMULATED_SERIAL, aps_orientation: int = 0, bus: int = 0, address: int = 1,
                 scenario_params: dict | None = None, time_scale: float = 1.0, fifo_bytes: int = FIFO_BYTES,
                 extra_event_rate: float = 0.0):
        super().__init__()
        from ..sim.scenes import SCENARIOS

        if scenario not in SCENARIOS:
            raise ParameterError(f"unknown scenario {scenario!r}; known: {', '.join(sorted(SCENARIOS))}")
        if duration_s is not None and not (isinstance(duration_s, (int, float)) and duration_s > 0):
            raise ParameterError(f"duration must be a positive number of seconds, got {duration_s!r}")
        if len(serial) > 8:
            raise ParameterError("a DAVIS serial number has at most 8 characters")
        for label, v in (("time_scale", time_scale), ("fifo_bytes", fifo_bytes)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or v != v or v == float("inf"):
                raise ParameterError(f"{label} must be a positive number, got {v!r}")
        if isinstance(extra_event_rate, bool) or not isinstance(extra_event_rate, (int, float)) \
                or not 0 <= extra_event_rate < 1e9:
            raise ParameterError(f"extra_event_rate must be 0..1e9 events/s, got {extra_event_rate!r}")
        self.scenario, self.seed, self.duration_s = scenario, int(seed), duration_s
        self.scenario_params = dict(scenario_params or {})
        self.faults = faults or Faults()
        self.realtime = bool(realtime)
        self.time_scale = float(time_scale)
        self.fifo_bytes = int(fifo_bytes)
        self.extra_event_rate = float(extra_event_rate)
        self._load_rng = np.random.default_rng([self.seed, 346])
        self.sensor = sensor
        self.serial = serial
        self.aps_orientation = int(aps_orientation) & 7
        self.bus, self.address = bus, address
        self.lock = threading.RLock()
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
        self._power_on()

    # -- device state -------------------------------------------------------------------------------
    def _power_on(self) -> None:
        """Register file after power-up; streaming state cleared."""
        w, h = self.sensor.width, self.sensor.height
        logic, adc, usb_clk, dev = EMULATED_CLOCKS
        f = self.faults
        self.regs: dict[tuple[int, int], int] = {
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_VERSION): f.logic,
            (P.SYSINFO.MODULE, P.SYSINFO.CHIP_IDENTIFIER): 5,  # DAVIS346B
            (P.SYSINFO.MODULE, P.SYSINFO.DEVICE_IS_MASTER): 1,
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_CLOCK): logic,
            (P.SYSINFO.MODULE, P.SYSINFO.ADC_CLOCK): adc,
            (P.SYSINFO.MODULE, P.SYSINFO.USB_CLOCK): usb_clk,
            (P.SYSINFO.MODULE, P.SYSINFO.CLOCK_DEVIATION): dev,
            (P.SYSINFO.MODULE, P.SYSINFO.LOGIC_PATCH): f.logic_patch,
            (P.DVS.MODULE, P.DVS.SIZE_COLUMNS): w, (P.DVS.MODULE, P.DVS.SIZE_ROWS): h,
            (P.DVS.MODULE, P.DVS.ORIENTATION_INFO): 0,
            (P.APS.MODULE, P.APS.SIZE_COLUMNS): w, (P.APS.MODULE, P.APS.SIZE_ROWS): h,
            (P.APS.MODULE, P.APS.ORIENTATION_INFO): self.aps_orientation,
            (P.APS.MODULE, P.APS.COLOR_FILTER): 0, (P.APS.MODULE, P.APS.HAS_GLOBAL_SHUTTER): 1,
            (P.APS.MODULE, P.APS.GLOBAL_SHUTTER): 1,
            (P.APS.MODULE, P.APS.START_COLUMN_0): 0, (P.APS.MODULE, P.APS.START_ROW_0): 0,
            (P.APS.MODULE, P.APS.END_COLUMN_0): w - 1, (P.APS.MODULE, P.APS.END_ROW_0): h - 1,
            (P.APS.MODULE, P.APS.EXPOSURE): round(4000 * self.adc_mhz),
            (P.APS.MODULE, P.APS.FRAME_INTERVAL): round(40000 * self.adc_mhz),
            (P.IMU.MODULE, P.IMU.TYPE): 1, (P.IMU.MODULE, P.IMU.ORIENTATION_INFO): 0,
            (P.MUX.MODULE, P.MUX.HAS_STATISTICS): 1, (P.DVS.MODULE, P.DVS.HAS_STATISTICS): 1,
            (P.DVS.MODULE, P.DVS.HAS_PIXEL_FILTER): 1, (P.DVS.MODULE, P.DVS.HAS_BACKGROUND_ACTIVITY_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_ROI_FILTER): 1, (P.DVS.MODULE, P.DVS.HAS_SKIP_FILTER): 1,
            (P.DVS.MODULE, P.DVS.HAS_POLARITY_FILTER): 1, (P.EXTINPUT.MODULE, P.EXTINPUT.HAS_GENERATOR): 1,
        }
        self._streaming = False
        self._encoder = None
        self._pending = bytearray()  # the device FIFO
        self.dvs_dropped = 0  # MUX STAT_DVS_DROPPED: DVS events dropped because the FIFO was full
        self.events_generated = 0  # DVS events the sensor produced (delivered + dropped)
        self.frames_skipped = 0  # frames not exposed because the FIFO was full at their start
        self.fifo_peak = 0
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
    def adc_mhz(self) -> float:
        return EMULATED_CLOCKS[1] * EMULATED_CLOCKS[3] / 1000.0

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
        return bool(r(P.MUX.MODULE, P.MUX.RUN) and r(P.MUX.MODULE, P.MUX.TIMESTAMP_RUN) and r(P.USB.MODULE, P.USB.RUN)
                    and r(P.MUX.MODULE, P.MUX.RUN_CHIP))

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

    # -- enumeration and descriptors -------------------------------------------------------------
    def enumerate_devices(self):
        with self.lock:
            try:
                self._check_plug()
            except usb.core.USBError:
                return iter(())
            return iter((self,))

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0300, bDeviceClass=0, bDeviceSubClass=0,
                     bDeviceProtocol=0, bMaxPacketSize0=9, idVendor=P.VID, idProduct=P.PID_FX3,
                     bcdDevice=0x0100 | (self.faults.firmware & 0xFF), iManufacturer=1, iProduct=2,
                     iSerialNumber=3, bNumConfigurations=1, address=self.address, bus=self.bus,
                     port_number=1, port_numbers=(1,), speed=4)

    def get_configuration_descriptor(self, dev, config):
        return _Desc(bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=1,
                     bConfigurationValue=P.CONFIGURATION, iConfiguration=0, bmAttributes=0x80, bMaxPower=50)

    def get_interface_descriptor(self, dev, intf, alt, config):
        return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=P.INTERFACE, bAlternateSetting=0,
                     bNumEndpoints=2, bInterfaceClass=0xFF, bInterfaceSubClass=0, bInterfaceProtocol=0,
                     iInterface=0)

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if ep == 0:
            return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=P.DEBUG_ENDPOINT, bmAttributes=3,
                         wMaxPacketSize=64, bInterval=1, bRefresh=0, bSynchAddress=0)
        return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=P.DATA_ENDPOINT, bmAttributes=2,
                     wMaxPacketSize=1024, bInterval=0, bRefresh=0, bSynchAddress=0)

    # -- handles ------------------------------------------------------------------------------------
    def open_device(self, dev):
        with self.lock:
            self._check_plug()
            if self.faults.permission_denied:
                raise _usb_error(errno.EACCES, "Access denied (insufficient permissions)")
            return _Handle(dev)

    def close_device(self, dev_handle):
        pass

    def set_configuration(self, dev_handle, config_value):
        self._check_plug()

    def get_configuration(self, dev_handle):
        self._check_plug()
        return P.CONFIGURATION

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._check_plug()

    def claim_interface(self, dev_handle, intf):
        self._check_plug()

    def release_interface(self, dev_handle, intf):
        self._check_plug()

    def clear_halt(self, dev_handle, ep):
        with self.lock:
            self._check_plug()
            self._log(ControlRecord("clear_halt", 0, 0, ep, 0, time.monotonic()))
            self._halted = False

    def reset_device(self, dev_handle):
        self._check_plug()

    def is_kernel_driver_active(self, dev_handle, intf):
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        pass

    # -- control transfers ---------------------------------------------------------------------------
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        with self.lock:
            self._check_plug()
            if bmRequestType == 0x80 and bRequest == 0x06 and wValue >> 8 == 3:  # GET_DESCRIPTOR string
                idx = wValue & 0xFF
                if idx == 0:
                    payload = bytes([4, 3, 0x09, 0x04])
                else:
                    text = {1: "iniVation", 2: "DAVIS FX3", 3: self.serial}.get(idx, "")
                    enc = text.encode("utf-16-le")
                    payload = bytes([2 + len(enc), 3]) + enc
                k = min(len(payload), len(data))
                data[:k] = array.array("B", payload[:k])
                return k
            if bmRequestType == P.REQ_OUT and bRequest == P.VR_FPGA_CONFIG:
                self._write(bRequest, wValue, wIndex, P.unpack_value(data))
                return len(data)
            if bmRequestType == P.REQ_OUT and bRequest == P.VR_FPGA_CONFIG_MULTIPLE:
                entries = P.unpack_multiple(data)
                if len(entries) != wValue:
                    raise _usb_error(errno.EPIPE, "Pipe error")
                for m, p, v in entries:
                    self._write(bRequest, m, p, v)
                return len(data)
            if bmRequestType == P.REQ_IN and bRequest == P.VR_FPGA_CONFIG:
                v = self._read(wValue, wIndex)
                self._log(ControlRecord("in", bRequest, wValue, wIndex, v, time.monotonic()))
                payload = P.pack_value(v)
                k = min(4, len(data))
                data[:k] = array.array("B", payload[:k])
                return k
            raise _usb_error(errno.EPIPE, "Pipe error")  # unsupported request: the device stalls EP0

    def _read(self, module: int, param: int) -> int:
        if module == P.MUX.MODULE and param in (P.MUX.STAT_DVS_DROPPED, P.MUX.STAT_DVS_DROPPED + 1):
            v = self.dvs_dropped  # 64-bit counter: MSB word, then LSB word
            return (v >> 32) & 0xFFFFFFFF if param == P.MUX.STAT_DVS_DROPPED else v & 0xFFFFFFFF
        if module in (P.MUX.MODULE, P.DVS.MODULE) and 81 <= param <= 92:
            return 0  # the other statistics counters: nothing dropped or filtered
        return self.reg(module, param)

    def _write(self, request: int, module: int, param: int, value: int) -> None:
        self._log(ControlRecord("out", request, module, param, value, time.monotonic()))
        key = (module, param)
        if module == P.SYSINFO.MODULE or key in ((P.DVS.MODULE, P.DVS.SIZE_COLUMNS), (P.DVS.MODULE, P.DVS.SIZE_ROWS),
                                                 (P.APS.MODULE, P.APS.SIZE_COLUMNS), (P.APS.MODULE, P.APS.SIZE_ROWS)):
            return  # read-only
        self.regs[key] = value
        if key == (P.APS.MODULE, P.APS.EXPOSURE) and self._rig is not None:
            us = max(value / self.adc_mhz, 1.0)
            self._rig.set_exposure("camera", us, 1.0)
        elif key == (P.MUX.MODULE, P.MUX.TIMESTAMP_RESET) and value and self._encoder is not None:
            self._pending += self._encoder.timestamp_reset().tobytes()
            self._base_us = self._rig.now_us if self._rig is not None else 0

    # -- streaming -----------------------------------------------------------------------------------
    def _ensure_rig(self) -> None:
        from ..sim.aps import ApsParams
        from ..sim.camera import SimRig
        from ..sim.scenes import make_scenario

        if self._rig is None:
            interval = max(int(round(self.reg(P.APS.MODULE, P.APS.FRAME_INTERVAL) / self.adc_mhz)), 3000)
            aps = ApsParams(frame_interval_us=interval, exposure_max_us=interval - 1000)
            duration_us = None if self.duration_s is None else int(round(self.duration_s * 1e6))
            scene = make_scenario(self.scenario, sensor=self.sensor, duration_us=duration_us, seed=self.seed,
                                  **self.scenario_params)
            exp_us = min(max(self.reg(P.APS.MODULE, P.APS.EXPOSURE) / self.adc_mhz, 1.0), aps.exposure_max_us)
            self._rig = SimRig(scene, {"camera": (exp_us, 1.0)}, aps=aps, seed=self.seed)
            self._gen = self._rig.packets()
        if self._encoder is None:  # streaming (re)starts: device time restarts at 0
            self._encoder = StreamEncoder(self.aps_orientation)
            self._base_us = self._rig.now_us
            self._pending += self._encoder.timestamp_reset().tobytes()
            self._frame_open = False
            self._next_imu_us = 0
            self._load_us = 0
            self._read_end_us = None
            self._late = 0
            self._wall_start = None if self.realtime else time.monotonic()

    @property
    def device_time_us(self) -> int:
        """Device time of the data produced so far (µs since streaming started)."""
        return 0 if self._encoder is None else self._encoder.now_us

    def _dev_t(self, t: int) -> int:
        return max(int(t) - self._base_us, self._encoder.now_us)

    def _sensor_us(self) -> int:
        """Device time up to which the sensor has been simulated (µs)."""
        return self._rig.now_us - self._base_us

    def _wall_us(self) -> float:
        """Device time the wall clock has reached since streaming started (realtime; µs)."""
        return (time.monotonic() - self._wall_start) * 1e6 * self.time_scale

    def _room(self) -> int | None:
        """Free bytes in the device FIFO (None: unbounded — not realtime, the device waits for the host;
        or data the emulator is late producing for a time when the host was reading)."""
        return self.fifo_bytes - self._fill() if self.realtime and not self._unbounded else None

    def _fill(self) -> int:
        """Bytes in the FIFO that occupy it (data produced late, see :meth:`_bulk_read_realtime`, do not)."""
        return len(self._pending) - self._late

    def _with_load(self, ev: np.ndarray, upto: int) -> np.ndarray:
        """``ev`` plus uniformly random events at ``extra_event_rate`` over [last load time, ``upto``) µs."""
        lo = max(self._load_us, self._encoder.now_us)
        if self.extra_event_rate <= 0 or upto <= lo:
            self._load_us = max(self._load_us, upto)
            return ev
        rng = self._load_rng
        n = int(rng.poisson(self.extra_event_rate * (upto - lo) / 1e6))
        self._load_us = upto
        if n == 0:
            return ev
        load = np.empty(n, EVENT_DTYPE)
        load["t"] = np.sort(rng.integers(lo, upto, n))
        load["x"] = rng.integers(0, self.sensor.width, n)
        load["y"] = rng.integers(0, self.sensor.height, n)
        load["p"] = rng.integers(0, 2, n, dtype=np.int8) * 2 - 1
        if ev.size == 0:
            return load
        both = np.concatenate([ev, load])
        return both[np.argsort(both["t"], kind="stable")]

    def _put_events(self, ev: np.ndarray) -> None:
        """Encode DVS events into the FIFO; in realtime, those that do not fit are dropped and counted."""
        if ev.size == 0:
            return
        enc = self._encoder
        n = ev.size
        self.events_generated += n
        room = self._room()
        if room is None:
            self._pending += enc.events(ev).tobytes()
            return
        if room <= 0:
            self.dvs_dropped += n
            return
        saved = enc.state.copy()
        words = enc.events(ev)
        k = n
        while words.nbytes > room and k > 0:  # keep the first k events that fit (k strictly decreases)
            enc.state[:] = saved
            k = k * room // words.nbytes
            words = enc.events(ev[:k]) if k else np.zeros(0, np.uint16)
        self.dvs_dropped += n - k
        self._pending += words.tobytes()

    def _put(self, words: np.ndarray) -> None:
        """Words the device never drops (time, specials, APS samples, IMU): into the FIFO whatever its fill."""
        self._pending += words.tobytes()

    def _produce(self, until: int | None = None) -> bool:
        """Simulate the sensor up to device time ``until`` µs (default: 1 ms on), encoding into the FIFO;
        False when the scenario is over."""
        enc = self._encoder
        r = self.reg
        if until is None:
            until = self._sensor_us() + 1000
        while self._sensor_us() < until:
            try:
                _, pk = next(self._gen)
            except StopIteration:
                self._scene_done = True
                break
            if isinstance(pk, np.ndarray):
                if r(P.DVS.MODULE, P.DVS.RUN):
                    ev = pk
                    if self._base_us:
                        ev = pk.copy()
                        ev["t"] -= self._base_us
                    ev = ev[ev["t"] >= enc.now_us]
                    upto = int(ev["t"][-1]) + 1 if ev.size else self._sensor_us() + 1
                    self._put_events(self._with_load(ev, upto))
                if r(P.IMU.MODULE, P.IMU.RUN_ACCELEROMETER) and enc.now_us >= self._next_imu_us:
                    self._put(enc.imu(enc.now_us, (0, -8192, 0, -1700, 0, 0, 0), accel_scale=1, gyro_scale=1))
                    self._next_imu_us = enc.now_us + 1000
            elif isinstance(pk, ExposureMarker):
                t = self._dev_t(pk.t_us)
                if r(P.DVS.MODULE, P.DVS.RUN):
                    self._put_events(self._with_load(np.zeros(0, EVENT_DTYPE), t))
                t = max(t, enc.now_us)
                if pk.kind == "start":
                    self._frame_open = bool(r(P.APS.MODULE, P.APS.RUN))
                    if self._frame_open and self.realtime and not self._unbounded and self._fill() >= self.fifo_bytes:
                        self._frame_open = False  # the APS waits on the stalled transfer: no frame
                        self.frames_skipped += 1
                    if self._frame_open:
                        cycles = int(round(self._rig.cams["camera"].exposure_us * self.adc_mhz))
                        roi = self._roi()
                        self._frame_roi = roi
                        h, w = roi[3] - roi[1] + 1, roi[2] - roi[0] + 1
                        gs = bool(r(P.APS.MODULE, P.APS.GLOBAL_SHUTTER))
                        self._put(enc.frame_start(t, roi, cycles, gs))
                        self._put(enc.readout(np.full((h, w), 1023, np.int64), False))
                        self._put(enc.special(t, EXPOSURE_START))
                elif self._frame_open:
                    self._put(enc.special(t, EXPOSURE_END))
            elif isinstance(pk, Frame) and self._frame_open:
                c0, r0, c1, r1 = self._frame_roi
                _, signal = cds_pair(pk.image[r0:r1 + 1, c0:c1 + 1])
                self._put(enc.readout(signal, True))
                self._put(enc.special(self._dev_t(self._rig.now_us), FRAME_END))
                self._frame_open = False
        if not self._unbounded:
            self.fifo_peak = max(self.fifo_peak, self._fill())
        return not self._scene_done

    def _roi(self) -> tuple[int, int, int, int]:
        w, h = self.sensor.width, self.sensor.height
        r = self.reg
        c0 = min(r(P.APS.MODULE, P.APS.START_COLUMN_0), w - 1)
        r0 = min(r(P.APS.MODULE, P.APS.START_ROW_0), h - 1)
        c1 = min(max(r(P.APS.MODULE, P.APS.END_COLUMN_0), c0), w - 1)
        r1 = min(max(r(P.APS.MODULE, P.APS.END_ROW_0), r0), h - 1)
        return c0, r0, c1, r1

    def _faults_and_state(self, ep) -> bool:
        """Checks every bulk read makes (unplug, halt, injected faults); returns whether the device streams."""
        self._check_plug()
        if ep != P.DATA_ENDPOINT:
            raise _usb_error(errno.EPIPE, "Pipe error")
        if self._halted:
            raise _usb_error(errno.EPIPE, "Pipe error")
        f = self.faults
        if f.unplug_after_s is not None and self.device_time_us >= f.unplug_after_s * 1e6:
            self.plugged = False
            self._unplugged_at = time.monotonic()
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        if f.stall_after_s is not None and not self._stalled_once and self.device_time_us >= f.stall_after_s * 1e6:
            self._stalled_once = True
            self._halted = True
            self.stalls += 1
            raise _usb_error(errno.EPIPE, "Pipe error")
        running = self._running()
        if running:
            self._ensure_rig()
        elif self._encoder is not None and not self.reg(P.USB.MODULE, P.USB.RUN):
            self._encoder = None  # stopped: the next start restarts device time
        return running

    def _take(self, view, got: int) -> int:
        """Move FIFO bytes into the host buffer ``view`` after its first ``got`` bytes; returns the new fill."""
        n = min(len(view) - got, len(self._pending))
        if n:
            view[got:got + n] = self._pending[:n]
            del self._pending[:n]
            self._late = max(0, self._late - n)
        return got + n

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        timeout_s = (timeout or 1000) / 1000.0
        if self.realtime:
            return self._bulk_read_realtime(ep, buff, timeout_s)
        with self.lock:
            running = self._faults_and_state(ep)
            if running and not self._pending and not self._scene_done:
                self._produce()
            n = self._take(memoryview(buff).cast("B"), 0)
            if n:
                self.bulk_reads += 1
            elif running and self._scene_done:
                self.stream_finished = True
        if n:
            return n
        time.sleep(min(timeout_s, 0.01))
        raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)

    def _bulk_read_realtime(self, ep, buff, timeout_s: float) -> int:
        """One transfer on the wall clock (see the module docstring): the data produced since the last
        transfer ended waited in the FIFO (bounded: DVS events dropped when full); from now on data
        flows into this transfer until it is full or the early-packet timer ends it.

        The emulator may itself fall behind the wall clock (a loaded machine); what it produces late
        for a time when the host was reading is not limited by the FIFO: only the time between two
        transfers is."""
        try:
            return self._transfer(ep, buff, timeout_s)
        finally:
            if self._wall_start is not None:
                self._read_end_us = self._wall_us()

    def _transfer(self, ep, buff, timeout_s: float) -> int:
        view = memoryview(buff).cast("B")
        t0 = time.monotonic()
        got = 0
        first = True
        while True:
            with self.lock:
                running = self._faults_and_state(ep)
                if running and not self._scene_done and self._wall_start is None:
                    # the simulator's first packet takes a while (start-up): device time 0 is when it is ready
                    self._produce(1)
                    self._wall_start = time.monotonic()
                if running and not self._scene_done:
                    target = self._wall_us()
                    if first:  # the gap since the last transfer: everything goes through the FIFO
                        late = self._read_end_us
                        if late is not None and self._sensor_us() < late:
                            self._unbounded = True  # late production for the previous transfer's time
                            try:
                                self._produce(int(late))
                            finally:
                                self._unbounded = False
                            self._late = len(self._pending)
                        self._produce(int(target))
                    else:  # inside the transfer: 1 ms at a time, each straight on to the host
                        while self._sensor_us() < target and got < len(view) and self._produce():
                            got = self._take(view, got)
                got = self._take(view, got)
                finished = running and self._scene_done and not self._pending
                if finished and not got:
                    self.stream_finished = True
            if finished and not got:
                time.sleep(min(timeout_s, 0.01))
                raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)
            first = False
            elapsed = time.monotonic() - t0
            if got == len(view) or (got and (finished or elapsed * 1e6 * self.time_scale >= EARLY_PACKET_US)):
                self.bulk_reads += 1
                return got
            if elapsed >= timeout_s:
                if got:
                    self.bulk_reads += 1
                    return got
                raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)
            time.sleep(min(0.002, max(0.0002, 250e-6 / self.time_scale)))

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        self._check_plug()
        time.sleep(min((timeout or 1000) / 1000.0, 0.01))
        raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)


def find_emulated(backend: EmulatedDavis346):
    """The emulated device as a ``usb.core.Device`` (None while unplugged)."""
    return usb.core.find(idVendor=P.VID, idProduct=P.PID_FX3, backend=backend)


__all__ = ["EmulatedDavis346", "Faults", "ControlRecord", "EMULATED_CLOCKS", "EMULATED_SERIAL", "find_emulated"]
