"""Open, configure, start and read a DAVIS camera over pyusb (real hardware or the emulator backend).

:func:`find_devices` lists DAVIS FX3 (0x152A:0x841A) and FX2 (0x152A:0x841B) devices;
:class:`DavisDevice` opens one, checks firmware (``bcdDevice & 0xFF``: older than required is refused,
newer accepted with a note) and logic (SYSINFO 0 == 18, patch >= 1), reads sizes, clocks and
capabilities, writes configuration (vendor requests 0xBF/0xC2) and runs the documented start/stop sequences (:mod:`.protocol`). :class:`BulkReader` reads the bulk
endpoint 0x82 on a dedicated thread into a queue bounded in sensor time; the driver reads through its
subclasses in :mod:`.transfers` (8 transfers of 8 KiB in flight through ``libusb1``, as libcaer, or pyusb reads
on a thread of their own), :class:`BulkReader` itself being the earlier single synchronous read (256 KiB by
default: at the full rate its oldest data waits ~7 ms before the transfer is full).

Reading at full rate: the DAVIS346 peaks at about 12 Mev/s (~70 MB/s of words with frames). The device's
early-packet delay (1 ms) ends a transfer early when the rate is low, so latency stays about 1 ms. When the
queue is full the reader stops reading and the device drops whole DVS events and counts them; those counters
(MUX/DVS statistics registers) are read by :meth:`DavisDevice.statistics` (see :class:`BulkReader`).
"""

from __future__ import annotations

import array
import errno as _errno
import queue
import threading
import time
from dataclasses import dataclass

import usb.core
import usb.util

from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError, DeviceNotFoundError


# -- backends ---------------------------------------------------------------------------------------
def usb_backend():
    """The libusb-1.0 backend: the system's, else the one shipped by ``libusb-package``."""
    import usb.backend.libusb1

    backend = usb.backend.libusb1.get_backend()
    if backend is None:
        try:
            import libusb_package

            backend = libusb_package.get_libusb1_backend()
        except ImportError:
            backend = None
    if backend is None:
        raise DeviceError(
            "libusb-1.0 is not available: install it (apt install libusb-1.0-0) or pip install libusb-package"
        )
    return backend


def _is_disconnect(e: BaseException) -> bool:
    return isinstance(e, usb.core.USBError) and (
        getattr(e, "errno", None) == _errno.ENODEV or "No such device" in str(e)
    )


def _is_access(e: BaseException) -> bool:
    return isinstance(e, usb.core.USBError) and (
        getattr(e, "errno", None) == _errno.EACCES or "Access denied" in str(e)
    )


def find_devices(backend) -> list:
    """All attached DAVIS FX3/FX2 devices (``usb.core.Device``), FX3 first."""
    out = []
    for pid in (P.PID_FX3, P.PID_FX2):
        out += list(usb.core.find(find_all=True, idVendor=P.VID, idProduct=pid, backend=backend))
    return out


@dataclass(frozen=True)
class DeviceInfo:
    """What ``necviz devices`` shows about one camera: ``error`` set when it could not be opened, ``notes``
    for what the user should know about a usable one; ``backend`` is ``"usb"`` (necviz's driver), ``"dv"``
    (dv-processing) or ``"emulated"``."""

    kind: str
    serial: str
    firmware: int
    logic: int | None
    bus: int | None
    address: int | None
    emulated: bool = False
    error: str = ""
    backend: str = "usb"
    notes: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        return "virtual" if self.emulated else f"bus {self.bus} addr {self.address}"

    @property
    def usable(self) -> bool:
        return not self.error


# -- one device -------------------------------------------------------------------------------------
class DavisDevice:
    """An opened, version-checked DAVIS camera.

    Attributes after opening: ``serial``, ``product`` ("DAVIS FX3"/"DAVIS FX2"), ``kind``
    (DAVIS346/DAVIS240/chip name), ``firmware``, ``logic_version``, ``logic_patch``, ``chip_id``,
    ``is_master``, ``clocks`` (:class:`~.protocol.Clocks`, actual MHz), ``dvs_size``/``aps_size``
    ((width, height) pixels in output coordinates: swapped when X/Y are inverted), ``dvs_orientation``,
    ``aps_orientation``, ``aps_color_filter``, ``has_global_shutter``, ``imu_type``, ``imu_orientation``,
    ``capabilities`` (dict of flags), ``notes`` (one-line remarks for the user, e.g. a firmware newer than
    required).
    """

    def __init__(self, dev, backend, emulated: bool = False):
        self.dev = dev
        self.backend = backend
        self.emulated = emulated
        self.product = P.PRODUCTS.get(dev.idProduct, f"0x{dev.idProduct:04x}")
        self.firmware = dev.bcdDevice & 0xFF
        self.bus, self.address = dev.bus, dev.address
        self.serial = "?"
        self.kind = "DAVIS346" if dev.idProduct == P.PID_FX3 else "DAVIS240"
        self.closed = False
        self.running = False
        #: one-line remarks about this camera worth showing the user (e.g. a firmware newer than required)
        self.notes: list[str] = []
        try:
            try:
                self._configure_usb()  # opens the device first: EACCES surfaces here
                self.serial = self._read_serial()
            except usb.core.USBError as e:
                raise self._translate(e, "open") from None
            self._check_versions()
            self._read_info()
        except DeviceError:
            self._dispose()
            raise

    # -- opening ------------------------------------------------------------------------------------
    def _read_serial(self) -> str:
        try:
            serial = usb.util.get_string(self.dev, self.dev.iSerialNumber) if self.dev.iSerialNumber else None
        except ValueError:  # no string descriptors
            serial = None
        if not serial:
            serial = f"TMP{(self.bus or 0) * 256 + (self.address or 0):05d}"
        return serial[:8]

    def _configure_usb(self) -> None:
        try:
            active = self.dev.get_active_configuration().bConfigurationValue
        except usb.core.USBError:
            active = None
        if active != P.CONFIGURATION:
            self.dev.set_configuration(P.CONFIGURATION)
        usb.util.claim_interface(self.dev, P.INTERFACE)

    def _name(self) -> str:
        return f"{self.kind} {self.serial}"

    def _translate(self, e: Exception, what: str) -> DeviceError:
        if _is_disconnect(e):
            return DeviceDisconnectedError(f"{self._name()} was unplugged ({what} failed)")
        if _is_access(e):
            return DeviceError(
                f"permission denied opening {self.product} at bus {self.bus} address {self.address} "
                "(no udev rule for 152a:84xx?)\n" + P.UDEV_INSTALL
            )
        return DeviceError(f"{self._name()}: {what} failed: {e}")

    def _check_versions(self) -> None:
        need = P.REQUIRED_FIRMWARE.get(self.dev.idProduct)
        if need is not None and self.firmware < need:  # older only: see P.REQUIRED_FIRMWARE
            raise DeviceError(
                f"{self.product} {self.serial} has firmware version {self.firmware}, older than the {need} "
                f"this driver needs: {P.FIRMWARE_REMEDY}"
            )
        if need is not None and self.firmware > need:
            self.notes.append(
                f"firmware {self.firmware} is newer than the {need} libcaer requires; not yet tried with this driver"
            )
        self.logic_version = self.get(P.SYSINFO.MODULE, P.SYSINFO.LOGIC_VERSION)
        if self.logic_version != P.REQUIRED_LOGIC:
            raise DeviceError(
                f"{self.product} {self.serial} has FPGA logic version {self.logic_version}, this driver "
                f"needs {P.REQUIRED_LOGIC}: {P.FIRMWARE_REMEDY}"
            )
        self.logic_patch = self.get(P.SYSINFO.MODULE, P.SYSINFO.LOGIC_PATCH)
        if self.logic_patch < P.REQUIRED_LOGIC_PATCH:
            raise DeviceError(
                f"{self.product} {self.serial} has logic patch level {self.logic_patch}, this driver "
                f"needs >= {P.REQUIRED_LOGIC_PATCH}: {P.FIRMWARE_REMEDY}"
            )

    def _read_info(self) -> None:
        g = self.get
        S, D, A, I = P.SYSINFO, P.DVS, P.APS, P.IMU
        self.chip_id = g(S.MODULE, S.CHIP_IDENTIFIER)
        chip = P.CHIP_NAMES.get(self.chip_id, f"chip {self.chip_id}")
        self.kind = (
            "DAVIS346" if self.chip_id in P.DAVIS346_CHIPS else "DAVIS240" if self.chip_id in P.DAVIS240_CHIPS else chip
        )
        self.chip = chip
        self.is_master = bool(g(S.MODULE, S.DEVICE_IS_MASTER))
        self.capabilities = {
            "dvs_pixel_filter": bool(g(D.MODULE, D.HAS_PIXEL_FILTER)),
            "dvs_background_activity_filter": bool(g(D.MODULE, D.HAS_BACKGROUND_ACTIVITY_FILTER)),
            "dvs_roi_filter": bool(g(D.MODULE, D.HAS_ROI_FILTER)),
            "dvs_skip_filter": bool(g(D.MODULE, D.HAS_SKIP_FILTER)),
            "dvs_polarity_filter": bool(g(D.MODULE, D.HAS_POLARITY_FILTER)),
            "dvs_statistics": bool(g(D.MODULE, D.HAS_STATISTICS)),
            "mux_statistics": bool(g(P.MUX.MODULE, P.MUX.HAS_STATISTICS)),
            "extinput_generator": bool(g(P.EXTINPUT.MODULE, P.EXTINPUT.HAS_GENERATOR)),
        }
        self.aps_color_filter = g(A.MODULE, A.COLOR_FILTER)
        self.has_global_shutter = bool(g(A.MODULE, A.HAS_GLOBAL_SHUTTER))
        # Sizes in output coordinates: with X/Y inverted (orientation bit 2) the row count is the width, as
        # libcaer's populateDeviceInfo (src/davis.c) swaps dvsSizeX/Y and apsSizeX/Y; the decoder, the ROI and
        # the pixel-filter registers then all speak output coordinates, as libcaer's do.
        self.dvs_orientation = g(D.MODULE, D.ORIENTATION_INFO)
        cols, rows = g(D.MODULE, D.SIZE_COLUMNS), g(D.MODULE, D.SIZE_ROWS)
        self.dvs_size = (rows, cols) if self.dvs_orientation & 4 else (cols, rows)
        self.aps_orientation = g(A.MODULE, A.ORIENTATION_INFO)
        cols, rows = g(A.MODULE, A.SIZE_COLUMNS), g(A.MODULE, A.SIZE_ROWS)
        self.aps_size = (rows, cols) if self.aps_orientation & 4 else (cols, rows)
        self.imu_type = g(I.MODULE, I.TYPE)
        self.imu_orientation = g(I.MODULE, I.ORIENTATION_INFO)
        #: SYSINFO logic, ADC and USB clocks (nominal MHz) and the deviation (x1000), as read
        self.clock_registers = (
            g(S.MODULE, S.LOGIC_CLOCK),
            g(S.MODULE, S.ADC_CLOCK),
            g(S.MODULE, S.USB_CLOCK),
            g(S.MODULE, S.CLOCK_DEVIATION),
        )
        self.clocks = P.Clocks.from_registers(*self.clock_registers)
        if min(self.dvs_size) <= 0 or min(self.aps_size) <= 0 or self.clocks.adc_mhz <= 0:
            raise DeviceError(
                f"{self._name()} reports an invalid size {self.dvs_size} or ADC clock {self.clocks.adc_mhz} MHz"
            )

    @property
    def info(self) -> dict:
        c = self.clocks
        return {
            "kind": self.kind,
            "product": self.product,
            "serial": self.serial,
            "firmware": self.firmware,
            "logic": self.logic_version,
            "logic_patch": self.logic_patch,
            "chip_id": self.chip_id,
            "chip": self.chip,
            "master": self.is_master,
            "bus": self.bus,
            "address": self.address,
            "emulated": self.emulated,
            "notes": list(self.notes),
            "dvs_size": self.dvs_size,
            "aps_size": self.aps_size,
            "dvs_orientation": self.dvs_orientation,
            "aps_orientation": self.aps_orientation,
            "imu_orientation": self.imu_orientation,
            "global_shutter": self.has_global_shutter,
            "color_filter": self.aps_color_filter,
            "imu_type": self.imu_type,
            "clocks_mhz": {"logic": c.logic_mhz, "adc": c.adc_mhz, "usb": c.usb_mhz},
            "clock_registers": dict(zip(("logic", "adc", "usb", "deviation"), self.clock_registers, strict=True)),
            "capabilities": dict(self.capabilities),
        }

    # -- configuration ------------------------------------------------------------------------------
    def set(self, module: int, param: int, value: int) -> None:
        """Write one register (vendor request 0xBF, value big-endian uint32)."""
        try:
            self.dev.ctrl_transfer(P.REQ_OUT, P.VR_FPGA_CONFIG, module, param, P.pack_value(value))
        except usb.core.USBError as e:
            raise self._translate(e, f"writing config ({module}, {param})") from None

    def get(self, module: int, param: int) -> int:
        """Read one register (vendor request 0xBF IN)."""
        try:
            data = self.dev.ctrl_transfer(P.REQ_IN, P.VR_FPGA_CONFIG, module, param, 4)
        except usb.core.USBError as e:
            raise self._translate(e, f"reading config ({module}, {param})") from None
        if len(data) != 4:
            raise DeviceError(f"{self._name()}: config ({module}, {param}) returned {len(data)} bytes, expected 4")
        return P.unpack_value(data)

    def get64(self, module: int, param: int) -> int:
        """A 64-bit statistics register: ``param`` holds the high word, ``param + 1`` the low word."""
        return self.get(module, param) << 32 | self.get(module, param + 1)

    def set_multiple(self, entries) -> None:
        """Write several registers with vendor request 0xC2 (in chunks of 682 entries), in order."""
        entries = list(entries)
        for i in range(0, len(entries), P.MULTIPLE_MAX_ENTRIES):
            chunk = entries[i : i + P.MULTIPLE_MAX_ENTRIES]
            try:
                self.dev.ctrl_transfer(P.REQ_OUT, P.VR_FPGA_CONFIG_MULTIPLE, len(chunk), 0, P.pack_multiple(chunk))
            except usb.core.USBError as e:
                raise self._translate(e, "writing config (multiple)") from None

    def us_to_cycles(self, us: float) -> int:
        return self.clocks.us_to_adc_cycles(us)

    def set_exposure_us(self, exposure_us: float) -> int:
        """APS exposure: register = round(µs x actual ADC clock MHz); returns the register value."""
        us = min(max(float(exposure_us), 0.0), P.EXPOSURE_MAX_US)
        cycles = self.us_to_cycles(us)
        self.set(P.APS.MODULE, P.APS.EXPOSURE, cycles)
        return cycles

    def set_frame_interval_us(self, interval_us: float) -> int:
        """Time between frame starts (µs; best effort on the device); returns the register value."""
        us = min(max(float(interval_us), 0.0), P.FRAME_INTERVAL_MAX_US)
        cycles = self.us_to_cycles(us)
        self.set(P.APS.MODULE, P.APS.FRAME_INTERVAL, cycles)
        return cycles

    def set_global_shutter(self, on: bool) -> None:
        """Global (True) or rolling shutter; kept in sync with chip-config parameter 142."""
        on = bool(on) and self.has_global_shutter
        self.set(P.APS.MODULE, P.APS.GLOBAL_SHUTTER, int(on))
        self.set(P.BIAS.MODULE, 142, int(on))

    def set_roi(self, start_col: int, start_row: int, end_col: int, end_row: int) -> None:
        """APS region of interest (inclusive, sensor pixels): APS off, 4 values, APS back on, one request."""
        w, h = self.aps_size
        if not (0 <= start_col <= end_col < w and 0 <= start_row <= end_row < h):
            raise DeviceError(f"ROI ({start_col}, {start_row})-({end_col}, {end_row}) does not fit the {w}x{h} array")
        A = P.APS
        run = [(A.MODULE, A.RUN, 1)] if self.running else []
        self.set_multiple(
            [
                (A.MODULE, A.RUN, 0),
                (A.MODULE, A.START_COLUMN_0, start_col),
                (A.MODULE, A.START_ROW_0, start_row),
                (A.MODULE, A.END_COLUMN_0, end_col),
                (A.MODULE, A.END_ROW_0, end_row),
            ]
            + run
        )

    def set_dvs_filters(
        self, background_activity_us: float | None = 2000.0, refractory_us: float | None = None
    ) -> None:
        """DVS background-activity and refractory filters (times in µs, 250 µs units on the device; None = off)."""
        D = P.DVS
        entries = []
        if self.capabilities.get("dvs_background_activity_filter"):
            ba = background_activity_us
            entries += [
                (D.MODULE, D.FILTER_BACKGROUND_ACTIVITY, int(ba is not None)),
                (D.MODULE, D.FILTER_BACKGROUND_ACTIVITY_TIME, max(1, round((ba or 2000) / 250))),
                (D.MODULE, D.FILTER_REFRACTORY_PERIOD, int(refractory_us is not None)),
                (D.MODULE, D.FILTER_REFRACTORY_PERIOD_TIME, max(1, round((refractory_us or 250) / 250))),
            ]
        if entries:
            self.set_multiple(entries)

    def set_biases(self, biases: dict[int, int]) -> None:
        """Write bias / chip-config words (module 5 parameter -> word)."""
        self.set_multiple([(P.BIAS.MODULE, p, v) for p, v in biases.items()])

    def send_default_config(self, exposure_us: float = 4000.0, frame_interval_us: float = 40000.0) -> None:
        """Biases, chip configuration and FPGA defaults (as libcaer's ``sendDefaultConfig``)."""
        M, D, A, I, E = P.MUX, P.DVS, P.APS, P.IMU, P.EXTINPUT
        self.set_biases(P.default_biases(self.chip_id))
        self.set_biases(P.default_chip_config(self.chip_id))
        w, h = self.dvs_size
        aw, ah = self.aps_size
        entries = [
            (M.MODULE, M.DROP_EXTINPUT_ON_TRANSFER_STALL, 1),
            (M.MODULE, M.DROP_DVS_ON_TRANSFER_STALL, 1),
            (D.MODULE, D.WAIT_ON_TRANSFER_STALL, 0),
            (D.MODULE, D.EXTERNAL_AER_CONTROL, 0),
        ]
        if self.capabilities["dvs_pixel_filter"]:
            for r, c in zip(D.FILTER_PIXEL_ROW, D.FILTER_PIXEL_COLUMN, strict=True):
                entries += [(D.MODULE, r, h), (D.MODULE, c, w)]  # out of range = disabled
        if self.capabilities["dvs_background_activity_filter"]:
            entries += [
                (D.MODULE, D.FILTER_BACKGROUND_ACTIVITY, 1),
                (D.MODULE, D.FILTER_BACKGROUND_ACTIVITY_TIME, 8),
                (D.MODULE, D.FILTER_REFRACTORY_PERIOD, 0),
                (D.MODULE, D.FILTER_REFRACTORY_PERIOD_TIME, 1),
            ]
        if self.capabilities["dvs_roi_filter"]:
            entries += [
                (D.MODULE, D.ROI_START_COLUMN, 0),
                (D.MODULE, D.ROI_START_ROW, 0),
                (D.MODULE, D.ROI_END_COLUMN, w - 1),
                (D.MODULE, D.ROI_END_ROW, h - 1),
            ]
        if self.capabilities["dvs_skip_filter"]:
            entries += [(D.MODULE, D.SKIP_EVENTS, 0), (D.MODULE, D.SKIP_EVENTS_EVERY, 5)]
        if self.capabilities["dvs_polarity_filter"]:
            entries += [
                (D.MODULE, D.POLARITY_FLATTEN, 0),
                (D.MODULE, D.POLARITY_SUPPRESS, 0),
                (D.MODULE, D.POLARITY_SUPPRESS_TYPE, 0),
            ]
        entries += [
            (A.MODULE, A.WAIT_ON_TRANSFER_STALL, 1),
            (A.MODULE, A.GLOBAL_SHUTTER, int(self.has_global_shutter)),
            (P.BIAS.MODULE, 142, int(self.has_global_shutter)),
            (A.MODULE, A.START_COLUMN_0, 0),
            (A.MODULE, A.START_ROW_0, 0),
            (A.MODULE, A.END_COLUMN_0, aw - 1),
            (A.MODULE, A.END_ROW_0, ah - 1),
            (A.MODULE, A.EXPOSURE, self.us_to_cycles(exposure_us)),
            (A.MODULE, A.FRAME_INTERVAL, self.us_to_cycles(frame_interval_us)),
            (I.MODULE, I.SAMPLE_RATE_DIVIDER, 0),
            (I.MODULE, I.ACCEL_DLPF, 1),
            (I.MODULE, I.ACCEL_FULL_SCALE, 1),
        ]
        if self.imu_type == 2:
            entries.append((I.MODULE, I.GYRO_DLPF, 1))
        entries += [
            (I.MODULE, I.GYRO_FULL_SCALE, 1),
            (E.MODULE, E.DETECT_RISING_EDGES, 0),
            (E.MODULE, E.DETECT_FALLING_EDGES, 0),
            (E.MODULE, E.DETECT_PULSES, 1),
            (E.MODULE, E.DETECT_PULSE_POLARITY, 1),
            (E.MODULE, E.DETECT_PULSE_LENGTH, max(1, round(10 * self.clocks.logic_mhz))),
        ]
        if self.capabilities["extinput_generator"]:
            entries.append((E.MODULE, E.RUN_GENERATOR, 0))
        entries.append((P.USB.MODULE, P.USB.EARLY_PACKET_DELAY, round(8 * 125 * self.clocks.usb_mhz)))
        self.set_multiple(entries)

    # -- start / stop -------------------------------------------------------------------------------
    def start(self, settle_s=P.START_SETTLE_S) -> None:
        """The documented start order: all off, clear halt, chip on (bias settle), USB/TS/MUX, producers."""
        for m, p, v in P.START_STOP_ALL:
            self.set(m, p, v)
        time.sleep(settle_s[0])
        self.clear_halt()
        for group, pause in ((P.START_CHIP, settle_s[1]), (P.START_TRANSPORT, settle_s[2]), (P.START_PRODUCERS, 0)):
            for m, p, v in group:
                self.set(m, p, v)
            if pause:
                time.sleep(pause)
        self.running = True

    def stop(self) -> None:
        """The documented stop order (producers, MUX/timestamps/USB, chip); ignored if already unplugged."""
        if not self.running:
            return
        self.running = False
        for m, p, v in P.STOP_SEQUENCE:
            try:
                self.set(m, p, v)
            except DeviceDisconnectedError:
                return

    def reset_timestamps(self) -> None:
        """Pulse MUX TIMESTAMP_RESET (the stream carries a timestamp-reset word)."""
        self.set_multiple([(P.MUX.MODULE, P.MUX.TIMESTAMP_RESET, 1), (P.MUX.MODULE, P.MUX.TIMESTAMP_RESET, 0)])

    def clear_halt(self) -> None:
        try:
            self.dev.clear_halt(P.DATA_ENDPOINT)
        except usb.core.USBError as e:
            raise self._translate(e, "clearing the endpoint halt") from None

    def statistics(self) -> dict:
        """Device counters (64-bit): events the FPGA dropped because USB stalled."""
        out = {}
        if self.capabilities.get("mux_statistics"):
            out["dvs_dropped_on_stall"] = self.get64(P.MUX.MODULE, P.MUX.STAT_DVS_DROPPED)
            out["extinput_dropped_on_stall"] = self.get64(P.MUX.MODULE, P.MUX.STAT_EXTINPUT_DROPPED)
        if self.capabilities.get("dvs_statistics"):
            out["dvs_dropped"] = self.get64(P.DVS.MODULE, P.DVS.STAT_EVENTS_DROPPED)
        return out

    def read(self, buffer: array.array, timeout_ms: int) -> int:
        """One bulk transfer from endpoint 0x82 into ``buffer``; returns the byte count (raises USBError)."""
        return self.dev.read(P.DATA_ENDPOINT, buffer, timeout_ms)

    def open_libusb1(self):
        """``(context, handle)`` of the ``libusb1`` package on this device, its interface claimed, for the
        asynchronous transfers of :class:`~.transfers.Libusb1Ring`; an emulated device gives its stand-ins
        (:mod:`.emulator_libusb1`).

        pyusb keeps the control transfers (they need no claimed interface); the interface, and with it the data
        endpoint, moves to the libusb1 handle (Linux lets one open file claim an interface at a time)."""
        if hasattr(self.backend, "open_libusb1"):
            return self.backend.open_libusb1()
        import usb1

        context = usb1.USBContext()
        context.open()
        try:
            for d in context.getDeviceIterator(skip_on_error=True):
                if (d.getBusNumber(), d.getDeviceAddress()) == (self.bus, self.address):
                    handle = d.open()
                    break
            else:
                raise DeviceDisconnectedError(f"{self._name()} was unplugged (not found by libusb1)")
            try:
                usb.util.release_interface(self.dev, P.INTERFACE)
            except usb.core.USBError:
                pass
            handle.claimInterface(P.INTERFACE)
        except usb1.USBError as e:
            context.close()
            if isinstance(e, usb1.USBErrorNoDevice):
                raise DeviceDisconnectedError(f"{self._name()} was unplugged (opening libusb1 transfers)") from None
            raise DeviceError(f"{self._name()}: opening libusb1 transfers failed: {e}") from None
        except BaseException:
            context.close()
            raise
        return context, handle

    def warm_up(self) -> None:
        """Before streaming: an emulated device's simulator compiles or loads its kernels (a few ms of its
        scene), so it keeps real time from its first packet; a USB device has nothing to ready."""
        if self.emulated:
            self.backend.warm_up()

    def close(self) -> None:
        """Stop (if running) and release the device. Idempotent."""
        if self.closed:
            return
        try:
            self.stop()
        except DeviceError:
            pass
        self._dispose()

    def _dispose(self) -> None:
        self.closed = True
        try:
            usb.util.dispose_resources(self.dev)
        except usb.core.USBError:
            pass


def open_device(backend, serial: str | None = None, emulated: bool = False) -> DavisDevice:
    """Open the DAVIS with ``serial`` (or the only/first one attached)."""
    devs = find_devices(backend)
    if not devs:
        raise DeviceNotFoundError("no DAVIS camera found (USB 152a:841a / 152a:841b)\n" + P.UDEV_HINT)
    if serial is None:
        return DavisDevice(devs[0], backend, emulated)
    seen = []
    for d in devs:
        s = _serial_of(d)
        if s is None:  # unreadable (e.g. permission denied): opening it raises the explanation
            dev = DavisDevice(d, backend, emulated)
            if dev.serial == serial:
                return dev
            s = dev.serial
            dev.close()
        if s == serial:
            return DavisDevice(d, backend, emulated)
        seen.append(s)
    raise DeviceNotFoundError(f"no DAVIS camera with serial {serial} (found {', '.join(seen)})")


def _serial_of(d) -> str | None:
    """Serial string of an unopened device (None if it cannot be read, e.g. permission denied)."""
    try:
        return usb.util.get_string(d, d.iSerialNumber) if d.iSerialNumber else None
    except (usb.core.USBError, ValueError):
        return None
    finally:
        try:
            usb.util.dispose_resources(d)
        except usb.core.USBError:
            pass


def describe(backend, emulated: bool = False) -> list[DeviceInfo]:
    """:class:`DeviceInfo` for every DAVIS on ``backend``; devices that cannot be opened carry ``error``."""
    out = []
    for d in find_devices(backend):
        kind = "DAVIS346" if d.idProduct == P.PID_FX3 else "DAVIS240"
        try:
            dev = DavisDevice(d, backend, emulated)
        except DeviceError as e:
            serial = _serial_of(d) or "?"
            out.append(
                DeviceInfo(
                    kind,
                    serial,
                    d.bcdDevice & 0xFF,
                    None,
                    d.bus,
                    d.address,
                    emulated,
                    str(e).splitlines()[0],
                    backend="emulated" if emulated else "usb",
                )
            )
            continue
        out.append(
            DeviceInfo(
                dev.kind,
                dev.serial,
                dev.firmware,
                dev.logic_version,
                dev.bus,
                dev.address,
                emulated,
                backend="emulated" if emulated else "usb",
                notes=tuple(dev.notes),
            )
        )
        dev.close()
    return out


# -- reader thread ----------------------------------------------------------------------------------
#: The DAVIS346's peak data rate assumed to size host buffers (bytes/s): 12 Mev/s at about 4.2 bytes
#: an event (an X word, plus the row and timestamp words shared by the events of a row and µs) and
#: 50 fps of 346 x 260 frames (two 16-bit readouts each, ~18 MB/s) — the ~34 M words/s of
#: ``necviz bench decode``'s full-rate stream, rounded up.
PEAK_BYTES_PER_S = 70_000_000


def thread_failed(e: BaseException) -> DeviceError:
    """What a reader thread that failed on something other than the device says (one line)."""
    return DeviceError(f"the reader thread failed: {type(e).__name__}: {e}")


class BulkReader:
    """Reads endpoint 0x82 on a daemon thread into a queue of ``(kind, payload)`` items.

    Kinds: ``"data"`` (bytes of one transfer; with ``decode``, ``"packets"``: ``(kind, packets, t_last_us,
    bytes, extra)``, what the transfer decoded to, see below), ``"disconnected"`` (the device vanished: ENODEV), ``"finished"`` (the backend says
    its stream is over: the emulator's ``stream_finished``), ``"error"`` (another USBError, payload =
    the exception). A stalled endpoint (EPIPE) is cleared and reading continues (counted in ``stalls``).

    Riding out a consumer that stops reading (a slow viewer, a long computation, a pause): pyusb has
    no asynchronous transfers, so this thread keeps one transfer in flight at all times and parks
    completed transfers in a queue. When the queue is full the thread stops reading
    (``backpressure_s`` counts the time, ``backpressure_events`` the times) instead of discarding
    transfers: a discarded transfer would cut the word stream anywhere (losing a wrap word shifts
    every later timestamp), whereas a device that is not read drops whole DVS events itself and counts
    them (MUX ``STAT_DVS_DROPPED``, with ``DROP_DVS_ON_TRANSFER_STALL`` on), which
    :meth:`DavisDevice.statistics` reads. Loss is therefore never silent.

    How full is full: with ``decode`` (a callable ``bytes -> (packets, t_last_us, extra)``, run here, on the
    reader thread: the kernels release the GIL), the queue is bounded in **sensor time** — it never
    holds packets more than ``buffer_s`` seconds of sensor time newer than the last packet the
    consumer took (``lag_peak_us`` is the deepest it has been), so a consumer that falls behind works
    on data at most ``buffer_s`` old and the rest is dropped (and counted) by the device, never held
    silently for seconds. A real sensor cannot run ahead of its clock, so the bound also keeps an
    emulated sensor paced by its reader (``necviz live --speed max``) within ``buffer_s`` of the
    consumer. Without ``decode``, the bound is ``max_queued`` bytes (default ``buffer_s`` at the peak
    rate, :data:`PEAK_BYTES_PER_S`). Not covered: a stall of the whole process (the GIL held for tens
    of ms) stops this thread too; the transfer in flight and the device's own buffers then hold only a
    few ms at the peak rate, and what the device drops is reported the same way.
    ``queue_peak_bytes`` is the deepest the queue has been in bytes.

    This is the old single synchronous read (``CameraOptions(usb="single")``); the driver reads through a ring of
    transfers in flight by default (:mod:`.transfers`: ``libusb1``'s asynchronous transfers, or pyusb reads on a
    thread of their own), which keeps this class's queue, bound and accounting.
    """

    #: the USB library and the number of transfers in flight (:mod:`.transfers` for the rings)
    library = "single"
    transfers = 1

    def __init__(
        self,
        device: DavisDevice,
        transfer_size: int = 256 * 1024,
        timeout_ms: int = 100,
        buffer_s: float = 2.0,
        max_queued: int | None = None,
        decode=None,
    ):
        self.device = device
        self.transfer_size = int(transfer_size)
        self.timeout_ms = int(timeout_ms)
        self.max_queued = int(max_queued if max_queued is not None else buffer_s * PEAK_BYTES_PER_S)
        self.decode = decode
        self.max_lag_us = int(round(buffer_s * 1e6))
        self.consumed_us: int | None = None  # sensor time of the last packets the consumer took
        self.queue: queue.Queue = queue.Queue()
        self.queued_bytes = 0
        self._room = threading.Condition()
        self._stop = threading.Event()
        self.stats = {
            "transfers": 0,
            "bytes": 0,
            "stalls": 0,
            "timeouts": 0,
            "backpressure_s": 0.0,
            "backpressure_events": 0,
            "queue_peak_bytes": 0,
            "lag_peak_us": 0,
        }
        self.thread = threading.Thread(target=self._run_guarded, name=f"necviz-davis-{device.serial}", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        with self._room:
            self._room.notify_all()
        if self.thread.is_alive() and threading.current_thread() is not self.thread:
            self.thread.join(timeout=5.0)

    def get(self, timeout: float):
        """Next item, or None after ``timeout`` seconds without one."""
        try:
            item = self.queue.get(timeout=timeout)
        except queue.Empty:
            return None
        if item[0] in ("data", "packets"):
            with self._room:
                if item[0] == "data":
                    self.queued_bytes -= len(item[1])
                else:
                    self.queued_bytes -= item[3]
                    self.consumed_us = item[2]
                self._room.notify()
        return item

    def _full(self, n: int, t_us: int | None) -> bool:
        """Whether ``n`` more bytes reaching sensor time ``t_us`` (None: not decoded) overflow the queue."""
        if self.queued_bytes <= 0:
            return False  # a transfer always fits into an empty queue
        if t_us is not None and self.consumed_us is not None:
            return t_us - self.consumed_us > self.max_lag_us
        return self.queued_bytes + n > self.max_queued

    def _wait_for_room(self, n: int, t_us: int | None = None) -> bool:
        """Block until ``n`` more bytes (up to sensor time ``t_us``) fit in the queue (the device holds, then
        drops, meanwhile); False if stopped."""
        with self._room:
            if self._full(n, t_us):
                t0 = time.monotonic()
                self.stats["backpressure_events"] += 1
                while self._full(n, t_us) and not self._stop.is_set():
                    self._room.wait(0.05)
                self.stats["backpressure_s"] += time.monotonic() - t0
            if self._stop.is_set():
                return False
            self.queued_bytes += n
            self.stats["queue_peak_bytes"] = max(self.stats["queue_peak_bytes"], self.queued_bytes)
            if t_us is not None and self.consumed_us is not None:
                self.stats["lag_peak_us"] = max(self.stats["lag_peak_us"], int(t_us - self.consumed_us))
            return True

    def _read_failed(self, e: usb.core.USBError):
        """What a failed read means: None to read on (a timeout; a stall, cleared and counted), else the
        item that ends the stream (``("finished", None)``, ``("disconnected", e)`` or ``("error", e)``)."""
        dev = self.device
        if isinstance(e, usb.core.USBTimeoutError) or getattr(e, "errno", None) == _errno.ETIMEDOUT:
            self.stats["timeouts"] += 1
            return ("finished", None) if getattr(dev.backend, "stream_finished", False) else None
        if _is_disconnect(e):
            return ("disconnected", e)
        if getattr(e, "errno", None) == _errno.EPIPE or "Pipe error" in str(e):
            self.stats["stalls"] += 1
            try:
                dev.dev.clear_halt(P.DATA_ENDPOINT)
                return None
            except usb.core.USBError as e2:
                return ("disconnected", e2) if _is_disconnect(e2) else ("error", e2)
        return ("error", e)

    def _deliver(self, data, n: int, transfers: int = 1) -> bool:
        """Hand one transfer's first ``n`` bytes on (decoded if asked), waiting for room; False if stopped.
        ``transfers``: how many transfers (completed back to back, joined by a ring) the bytes are."""
        self.stats["transfers"] += transfers
        self.stats["bytes"] += n
        if self.decode is None:
            raw = bytes(data[:n])
            if not self._wait_for_room(n):
                return False
            self.queue.put(("data", raw))
            return True
        packets, t_last, extra = self.decode(data[:n])
        if self.consumed_us is None:
            self.consumed_us = t_last  # the stream's first sensor time: the consumer starts there
        if not self._wait_for_room(n, t_last):
            return False
        self.queue.put(("packets", packets, t_last, n, extra))
        return True

    def _run_guarded(self) -> None:
        try:
            self._run()
        except Exception as e:  # not the device's: a bug (in decoding, say) ends the stream in one line
            self.queue.put(("error", thread_failed(e)))  # instead of leaving the consumer waiting forever

    def _run(self) -> None:
        buf = array.array("B", bytes(self.transfer_size))
        view = memoryview(buf)
        dev = self.device
        while not self._stop.is_set():
            try:
                n = dev.read(buf, self.timeout_ms)
            except usb.core.USBError as e:
                if self._stop.is_set():
                    return
                end = self._read_failed(e)
                if end is None:
                    continue
                self.queue.put(end)
                return
            if n > 0 and not self._deliver(view, n):
                return
