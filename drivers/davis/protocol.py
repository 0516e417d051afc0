"""DAVIS USB protocol constants: ids, vendor requests, the module/parameter map and bias encodings.

Facts from libcaer's public source (github.com/inivation/libcaer, 3.x: ``include/libcaer/devices/davis.h``,
``src/davis_common.h``, ``src/davis.c``, ``src/usb_utils.h``; logic 18 register map), summarised in
docs/davis-protocol.md. Nothing here talks to a device; :mod:`.device` and :mod:`.emulator` both use
these names so the driver and the emulated DAVIS346 agree by construction and the tests can check
both against the documented protocol.

Units: clocks in MHz, times in µs, register values as the FPGA stores them (APS exposure and
frame interval in ADC-clock cycles).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

# -- identity ------------------------------------------------------------------------------------
VID = 0x152A
PID_FX3 = 0x841A  #: DAVIS FX3 boards (DAVIS346)
PID_FX2 = 0x841B  #: DAVIS FX2 boards (DAVIS240)
PRODUCTS = {PID_FX3: "DAVIS FX3", PID_FX2: "DAVIS FX2"}
#: Oldest firmware version (``bcdDevice & 0xFF``) per product id: libcaer's ``DAVIS_FX3_REQUIRED_FIRMWARE_VERSION``
#: and ``DAVIS_FX2_REQUIRED_FIRMWARE_VERSION`` (``src/davis.h``). Older firmware is refused, newer is opened with a
#: note. libcaer's ``usbDeviceOpen`` (``src/usb_utils.c``) refused only older firmware (``firmwareVersion <
#: required``) until its commit e1c6065 (2018-09, "check for exact required firmware/logic versions"), and refuses
#: any other version since (so does the libcaer inside dv-processing 2.0). necviz keeps the older rule for the
#: firmware only: the FX3/FX2 firmware carries the two vendor requests and the bulk endpoint, while the register
#: map and the word stream belong to the FPGA logic, which is still checked exactly (:data:`REQUIRED_LOGIC`).
REQUIRED_FIRMWARE = {PID_FX3: 6, PID_FX2: 4}
REQUIRED_LOGIC = 18  #: SYSINFO LOGIC_VERSION must equal this
REQUIRED_LOGIC_PATCH = 1  #: SYSINFO LOGIC_PATCH must be at least this

DATA_ENDPOINT = 0x82  #: bulk IN endpoint carrying the 16-bit word stream
DEBUG_ENDPOINT = 0x81  #: interrupt IN endpoint (FX3 firmware messages; unused by this driver)
CONFIGURATION = 1
INTERFACE = 0

# -- vendor requests -----------------------------------------------------------------------------
REQ_OUT = 0x40  #: VENDOR | RECIPIENT_DEVICE, host to device
REQ_IN = 0xC0  #: VENDOR | RECIPIENT_DEVICE, device to host
VR_FPGA_CONFIG = 0xBF  #: wValue = module, wIndex = parameter, data = uint32 big-endian
VR_FPGA_CONFIG_MULTIPLE = 0xC2  #: wValue = N entries, data = N x (u8 module, u8 param, u32 BE)
MULTIPLE_MAX_ENTRIES = 682  #: entries per 0xC2 request (4096-byte buffer)


def pack_value(value: int) -> bytes:
    """A register value as the 4 big-endian bytes of a 0xBF request."""
    return struct.pack(">I", int(value) & 0xFFFFFFFF)


def unpack_value(data) -> int:
    """The uint32 of a 0xBF IN reply (4 big-endian bytes)."""
    return struct.unpack(">I", bytes(data[:4]))[0]


def pack_multiple(entries) -> bytes:
    """Payload of a 0xC2 request for ``[(module, param, value), ...]``."""
    return b"".join(struct.pack(">BBI", m, p, int(v) & 0xFFFFFFFF) for m, p, v in entries)


def unpack_multiple(data) -> list[tuple[int, int, int]]:
    """Inverse of :func:`pack_multiple` (used by the emulator)."""
    raw = bytes(data)
    return [struct.unpack_from(">BBI", raw, i) for i in range(0, len(raw) - len(raw) % 6, 6)]


# -- module / parameter map (logic 18) -----------------------------------------------------------
class MUX:
    MODULE = 0
    RUN = 0
    TIMESTAMP_RUN = 1
    TIMESTAMP_RESET = 2
    RUN_CHIP = 3
    DROP_EXTINPUT_ON_TRANSFER_STALL = 4
    DROP_DVS_ON_TRANSFER_STALL = 5
    HAS_STATISTICS = 80
    STAT_EXTINPUT_DROPPED = 81  # 64-bit: 81 MSB, 82 LSB
    STAT_DVS_DROPPED = 83  # 64-bit: 83 MSB, 84 LSB


class DVS:
    MODULE = 1
    SIZE_COLUMNS = 0
    SIZE_ROWS = 1
    ORIENTATION_INFO = 2  # bit2 invertXY
    RUN = 3
    WAIT_ON_TRANSFER_STALL = 4
    EXTERNAL_AER_CONTROL = 5
    HAS_PIXEL_FILTER = 10
    FILTER_PIXEL_ROW = (11, 13, 15, 17, 19, 21, 23, 25)
    FILTER_PIXEL_COLUMN = (12, 14, 16, 18, 20, 22, 24, 26)
    HAS_BACKGROUND_ACTIVITY_FILTER = 30
    FILTER_BACKGROUND_ACTIVITY = 31
    FILTER_BACKGROUND_ACTIVITY_TIME = 32  # 250 µs units
    FILTER_REFRACTORY_PERIOD = 33
    FILTER_REFRACTORY_PERIOD_TIME = 34  # 250 µs units
    HAS_ROI_FILTER = 40
    ROI_START_COLUMN = 41
    ROI_START_ROW = 42
    ROI_END_COLUMN = 43
    ROI_END_ROW = 44
    HAS_SKIP_FILTER = 50
    SKIP_EVENTS = 51
    SKIP_EVENTS_EVERY = 52
    HAS_POLARITY_FILTER = 60
    POLARITY_FLATTEN = 61
    POLARITY_SUPPRESS = 62
    POLARITY_SUPPRESS_TYPE = 63
    HAS_STATISTICS = 80
    STAT_EVENTS_ROW = 81
    STAT_EVENTS_COLUMN = 83
    STAT_EVENTS_DROPPED = 85
    STAT_FILTERED_PIXELS = 87
    STAT_FILTERED_BA = 89
    STAT_FILTERED_REFRACTORY = 91


class APS:
    MODULE = 2
    SIZE_COLUMNS = 0
    SIZE_ROWS = 1
    ORIENTATION_INFO = 2  # bit2 invertXY, bit1 flipX, bit0 flipY
    COLOR_FILTER = 3
    RUN = 4
    WAIT_ON_TRANSFER_STALL = 5
    HAS_GLOBAL_SHUTTER = 6
    GLOBAL_SHUTTER = 7
    START_COLUMN_0 = 8
    START_ROW_0 = 9
    END_COLUMN_0 = 10
    END_ROW_0 = 11
    EXPOSURE = 12  # ADC-clock cycles
    FRAME_INTERVAL = 13  # ADC-clock cycles


class IMU:
    MODULE = 3
    TYPE = 0  # 0 none, 1 MPU6050/6150, 2 MPU9250
    ORIENTATION_INFO = 1  # bit2 flipX, bit1 flipY, bit0 flipZ
    RUN_ACCELEROMETER = 2
    RUN_GYROSCOPE = 3
    RUN_TEMPERATURE = 4
    SAMPLE_RATE_DIVIDER = 5
    ACCEL_DLPF = 6
    ACCEL_FULL_SCALE = 7
    GYRO_DLPF = 9
    GYRO_FULL_SCALE = 10


class EXTINPUT:
    MODULE = 4
    RUN_DETECTOR = 0
    DETECT_RISING_EDGES = 1
    DETECT_FALLING_EDGES = 2
    DETECT_PULSES = 3
    DETECT_PULSE_POLARITY = 4
    DETECT_PULSE_LENGTH = 5  # logic-clock cycles
    HAS_GENERATOR = 10
    RUN_GENERATOR = 11


class BIAS:
    MODULE = 5  # = CHIP; chip-config parameters are >= 128


class SYSINFO:
    MODULE = 6
    LOGIC_VERSION = 0
    CHIP_IDENTIFIER = 1
    DEVICE_IS_MASTER = 2
    LOGIC_CLOCK = 3  # MHz
    ADC_CLOCK = 4  # MHz
    USB_CLOCK = 5  # MHz
    CLOCK_DEVIATION = 6  # x1000
    LOGIC_PATCH = 7


class USB:
    MODULE = 9
    RUN = 0
    EARLY_PACKET_DELAY = 1  # USB-clock cycles


CHIP_NAMES = {
    0: "DAVIS240A",
    1: "DAVIS240B",
    2: "DAVIS240C",
    3: "DAVIS128",
    4: "DAVIS346A",
    5: "DAVIS346B",
    6: "DAVIS640",
    7: "DAVIS640H",
    8: "DAVIS208",
    9: "DAVIS346C",
}
DAVIS240_CHIPS = (0, 1, 2)
DAVIS346_CHIPS = (4, 5, 9)

#: Register range of APS EXPOSURE (documented 0-4194303 µs) and FRAME_INTERVAL (0-8388607 µs).
EXPOSURE_MAX_US = 4_194_303
FRAME_INTERVAL_MAX_US = 8_388_607

# -- biases ---------------------------------------------------------------------------------------
#: Coarse current table (pA) of the coarse/fine bias generator: I = C[coarse] * fine / 255.
COARSE_CURRENT_PA = (11, 94, 756, 6054, 48437, 387500, 3100000, 24800000)


def vdac(voltage: int, current: int) -> int:
    """VDAC bias word: ``voltage`` (6 bits) | ``current`` (3 bits) << 6."""
    if not (0 <= voltage < 64 and 0 <= current < 8):
        raise ValueError(f"VDAC voltage must be 0..63 and current 0..7, got {voltage}, {current}")
    return (voltage & 0x3F) | (current & 0x7) << 6


def coarse_fine(
    coarse: int,
    fine: int,
    *,
    enabled: bool = True,
    sex_n: bool = True,
    type_normal: bool = True,
    current_level_normal: bool = True,
) -> int:
    """Coarse/fine bias word: bit0 enabled, bit1 sexN, bit2 typeNormal, bit3 currentLevelNormal,
    ``fine`` (8 bits) << 4, ``coarse`` (3 bits) << 12."""
    if not (0 <= coarse < 8 and 0 <= fine < 256):
        raise ValueError(f"coarse must be 0..7 and fine 0..255, got {coarse}, {fine}")
    return (
        int(enabled)
        | int(sex_n) << 1
        | int(type_normal) << 2
        | int(current_level_normal) << 3
        | fine << 4
        | coarse << 12
    )


def shifted_source(ref: int, reg: int, *, op_mode: int = 0, voltage_level: int = 0) -> int:
    """Shifted-source bias word: opMode bits 0-1, voltageLevel bits 2-3, ref (6 bits) << 4, reg (6 bits) << 10."""
    return (op_mode & 3) | (voltage_level & 3) << 2 | (ref & 0x3F) << 4 | (reg & 0x3F) << 10


def bias_current_pa(coarse: int, fine: int) -> float:
    """Current (pA) of a coarse/fine setting."""
    return COARSE_CURRENT_PA[coarse] * fine / 255.0


def _n(c, f):
    return coarse_fine(c, f, sex_n=True)


def _p(c, f):
    return coarse_fine(c, f, sex_n=False)


#: DAVIS346 default biases, parameter -> word (libcaer's documented defaults).
DAVIS346_BIASES = {
    0: vdac(27, 6),  # APSOVERFLOWLEVEL
    1: vdac(21, 6),  # APSCAS
    2: vdac(32, 7),  # ADCREFHIGH
    3: vdac(1, 7),  # ADCREFLOW
    4: vdac(21, 7),  # ADCTESTVOLTAGE
    8: _n(5, 164),  # LOCALBUFBN
    9: coarse_fine(7, 215, enabled=False),  # PADFOLLBN (N, off)
    10: _n(4, 39),  # DIFFBN
    11: _n(5, 255),  # ONBN
    12: _n(4, 1),  # OFFBN
    13: _n(6, 144),  # PIXINVBN
    14: _p(2, 58),  # PRBP
    15: _p(1, 16),  # PRSFBP
    16: _p(4, 25),  # REFRBP
    17: _p(6, 20),  # READOUTBUFBP
    18: _n(6, 219),  # APSROSFBN
    19: _p(5, 20),  # ADCCOMPBP
    20: _n(0, 1),  # COLSELLOWBN
    21: _p(6, 60),  # DACBUFBP
    22: _n(5, 49),  # LCOLTIMEOUTBN
    23: _n(6, 91),  # AEPDBN
    24: _p(4, 80),  # AEPUXBP
    25: _p(7, 152),  # AEPUYBP
    26: _n(5, 255),  # IFREFRBN
    27: _n(5, 255),  # IFTHRBN
    34: _n(5, 254),  # BIASBUFFER
    35: shifted_source(1, 33),  # SSP
    36: shifted_source(1, 33),  # SSN
}

#: DAVIS346 chip configuration (module 5, params >= 128), GLOBAL_SHUTTER (142) is written separately.
DAVIS346_CHIP_CONFIG = {
    128: 0,
    129: 0,
    130: 0,
    131: 0,
    132: 0,
    133: 0,
    134: 0,
    135: 0,
    136: 1,
    137: 0,
    138: 1,
    140: 0,
    141: 0,
    143: 1,
    144: 0,
}


def _n_cas(c, f):
    return coarse_fine(c, f, sex_n=True, type_normal=False)


#: DAVIS240 biases (old 22-branch generator), parameter -> word: libcaer's defaults
#: (``src/davis_common.h``, ``davisCommonSendDefaultChipConfig``, the ``IS_DAVIS240`` branch). Unlike the
#: DAVIS346 table, OFFBN is (4, 0), PADFOLLBN is enabled, and APSCASEPC and DIFFCASBNC are cascode N-type
#: (``typeNormal`` off).
DAVIS240_BIASES = {
    0: _n(4, 39),  # DIFFBN
    1: _n(5, 255),  # ONBN
    2: _n(4, 0),  # OFFBN
    3: _n_cas(5, 185),  # APSCASEPC
    4: _n_cas(5, 115),  # DIFFCASBNC
    5: _n(6, 219),  # APSROSFBN
    6: _n(5, 164),  # LOCALBUFBN
    7: _n(6, 144),  # PIXINVBN
    8: _p(2, 58),  # PRBP
    9: _p(1, 16),  # PRSFBP
    10: _p(4, 25),  # REFRBP
    11: _n(6, 91),  # AEPDBN
    12: _n(5, 49),  # LCOLTIMEOUTBN
    13: _p(4, 80),  # AEPUXBP
    14: _p(7, 152),  # AEPUYBP
    15: _n(5, 255),  # IFTHRBN
    16: _n(5, 255),  # IFREFRBN
    17: _n(7, 215),  # PADFOLLBN
    18: _n(6, 253),  # APSOVERFLOWLEVELBN
    19: _n(5, 254),  # BIASBUFFER
    20: shifted_source(1, 33),  # SSP
    21: shifted_source(1, 33),  # SSN
}
#: DAVIS240 chip configuration. libcaer's ``davisCommonSendDefaultChipConfig`` also writes
#: SPECIALPIXELCONTROL (139) = 0, which its ``davisCommonConfigSet`` passes on for DAVIS240 A/B only
#: (see :func:`default_chip_config`); SELECTGRAYCOUNTER (143) and TESTADC (144) do not exist on the DAVIS240.
DAVIS240_CHIP_CONFIG = {
    128: 0,
    129: 0,
    130: 0,
    131: 0,
    132: 0,
    133: 0,
    134: 0,
    135: 0,
    136: 1,
    137: 0,
    138: 1,
    140: 0,
    141: 0,
}
#: DAVIS240 A and B (chip ids 0, 1) have the special-pixel control bit.
DAVIS240_SPECIAL_PIXEL_CHIPS = (0, 1)


def default_biases(chip_id: int) -> dict[int, int]:
    """Default bias words (module 5 parameter -> value) for a chip identifier."""
    return dict(DAVIS240_BIASES if chip_id in DAVIS240_CHIPS else DAVIS346_BIASES)


def default_chip_config(chip_id: int) -> dict[int, int]:
    """Default chip-configuration words (module 5, params >= 128) for a chip identifier."""
    if chip_id in DAVIS240_SPECIAL_PIXEL_CHIPS:
        return {**DAVIS240_CHIP_CONFIG, 139: 0}  # SPECIALPIXELCONTROL off
    return dict(DAVIS240_CHIP_CONFIG if chip_id in DAVIS240_CHIPS else DAVIS346_CHIP_CONFIG)


# -- documented start / stop order ----------------------------------------------------------------
#: ``dataStart`` after the default configuration: everything off, then (after clearing the halt) the
#: chip, then USB/timestamps/MUX, then the producers. Each group is written in order; the driver
#: sleeps ``START_SETTLE_S`` after each of the first three groups.
START_STOP_ALL = (
    (DVS.MODULE, DVS.RUN, 0),
    (APS.MODULE, APS.RUN, 0),
    (IMU.MODULE, IMU.RUN_ACCELEROMETER, 0),
    (IMU.MODULE, IMU.RUN_GYROSCOPE, 0),
    (IMU.MODULE, IMU.RUN_TEMPERATURE, 0),
    (EXTINPUT.MODULE, EXTINPUT.RUN_DETECTOR, 0),
    (MUX.MODULE, MUX.RUN, 0),
    (MUX.MODULE, MUX.TIMESTAMP_RUN, 0),
    (USB.MODULE, USB.RUN, 0),
    (MUX.MODULE, MUX.RUN_CHIP, 0),
)
START_CHIP = ((MUX.MODULE, MUX.RUN_CHIP, 1),)
START_TRANSPORT = ((USB.MODULE, USB.RUN, 1), (MUX.MODULE, MUX.TIMESTAMP_RUN, 1), (MUX.MODULE, MUX.RUN, 1))
START_PRODUCERS = (
    (DVS.MODULE, DVS.RUN, 1),
    (APS.MODULE, APS.RUN, 1),
    (IMU.MODULE, IMU.RUN_ACCELEROMETER, 1),
    (IMU.MODULE, IMU.RUN_GYROSCOPE, 1),
    (IMU.MODULE, IMU.RUN_TEMPERATURE, 1),
    (EXTINPUT.MODULE, EXTINPUT.RUN_DETECTOR, 1),
)
#: sleeps (s) after: stop-all (before clearing the halt), RUN_CHIP (bias settle), USB/TS/MUX run
START_SETTLE_S = (0.010, 0.200, 0.050)
#: ``dataStop``: producers off, then MUX/timestamps/USB, then the chip.
STOP_SEQUENCE = tuple((m, p, 0) for m, p, _ in START_PRODUCERS) + (
    (MUX.MODULE, MUX.RUN, 0),
    (MUX.MODULE, MUX.TIMESTAMP_RUN, 0),
    (USB.MODULE, USB.RUN, 0),
    (MUX.MODULE, MUX.RUN_CHIP, 0),
)


# -- user help -----------------------------------------------------------------------------------
UDEV_RULE = 'SUBSYSTEM=="usb", ATTR{idVendor}=="152a", ATTR{idProduct}=="84[0-1]?", MODE="0666"'
UDEV_INSTALL = (
    "add the udev rule\n"
    f"  {UDEV_RULE}\n"
    "to /etc/udev/rules.d/65-inivation.rules, run `sudo udevadm control --reload-rules && sudo udevadm trigger` "
    "and replug the camera"
)
UDEV_HINT = (
    "check that the camera is listed by `lsusb -d 152a:` (DAVIS346 = 152a:841a, DAVIS240 = 152a:841b); "
    "if it is but cannot be opened, " + UDEV_INSTALL
)
FIRMWARE_REMEDY = "update the camera's firmware and logic with iniVation's DV software (Flashy / dv-flashy)"


@dataclass(frozen=True)
class Clocks:
    """Actual clocks in MHz (nominal MHz x deviation / 1000, as the device reports them)."""

    logic_mhz: float
    adc_mhz: float
    usb_mhz: float

    @classmethod
    def from_registers(cls, logic: int, adc: int, usb: int, deviation: int) -> Clocks:
        d = (deviation or 1000) / 1000.0
        return cls(logic * d, adc * d, usb * d)

    def us_to_adc_cycles(self, us: float) -> int:
        """APS register value for ``us`` microseconds: ``round(us * adc_mhz)``."""
        return int(round(us * self.adc_mhz))

    def adc_cycles_to_us(self, cycles: int) -> float:
        return cycles / self.adc_mhz
