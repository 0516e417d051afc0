"""Raw captures of a DAVIS bulk stream: every USB transfer as it arrived, with the device's description.

``necviz devices --check --capture FILE`` records a camera's stream this way so that what a camera in the
field sends can be decoded again anywhere — a capture from the field becomes a decoder test. The file:

* the magic line ``NECVIZ-DAVIS-CAPTURE 1\\n``;
* ``uint32`` (little-endian) length, then that many bytes of UTF-8 JSON: the device as the driver read it
  (``DavisDevice.info`` plus the orientations, colour filter and IMU settings the decoder needs) and the
  registers the capture ran with (``exposure_cycles``, ``frame_interval_cycles``);
* one record per transfer: ``uint64`` nanoseconds since the capture started (host clock, when the transfer
  was handed over), ``uint32`` byte count, the bytes.

Records are appended as they arrive, so a capture cut short (a full disk, a crash) stays readable up to its
last whole record; :func:`read_capture` says so in ``truncated``.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from necviz.core.errors import NecvizError
from necviz.drivers.davis.decoder import DavisDecoder, DecoderOptions

MAGIC = b"NECVIZ-DAVIS-CAPTURE 1\n"
_RECORD = struct.Struct("<QI")
#: the device fields a capture's header keeps (everything the decoder and the report need)
HEADER_DEVICE_FIELDS = (
    "kind",
    "product",
    "serial",
    "firmware",
    "logic",
    "logic_patch",
    "chip_id",
    "chip",
    "master",
    "emulated",
    "dvs_size",
    "aps_size",
    "dvs_orientation",
    "aps_orientation",
    "color_filter",
    "global_shutter",
    "imu_type",
    "imu_orientation",
    "clocks_mhz",
    "clock_registers",
    "notes",
)


class CaptureError(NecvizError):
    """A file that is not a readable DAVIS capture."""


@dataclass
class Capture:
    """A capture read back: its header (``device``, ``registers``) and ``transfers`` as ``(t_ns, bytes)``."""

    device: dict
    registers: dict
    transfers: list[tuple[int, bytes]] = field(default_factory=list)
    truncated: bool = False

    @property
    def bytes(self) -> int:
        return sum(len(b) for _, b in self.transfers)

    def decoder_options(self) -> DecoderOptions:
        """The stream format the device described (sizes in output coordinates, orientations, colour, IMU)."""
        d = self.device
        (w, h), (aw, ah) = d["dvs_size"], d["aps_size"]
        return DecoderOptions(
            int(w),
            int(h),
            aps_width=int(aw),
            aps_height=int(ah),
            dvs_invert_xy=bool(int(d.get("dvs_orientation", 0)) & 4),
            aps_orientation=int(d.get("aps_orientation", 0)),
            imu_orientation=int(d.get("imu_orientation", 0)),
            imu_model=int(d.get("imu_type", 1)) or 1,
            adc_shift=1 if d.get("kind") == "DAVIS240" else 0,
            color_filter=int(d.get("color_filter", 0)) if int(d.get("color_filter", 0)) in range(9) else 0,
        )

    def decoder(self) -> DavisDecoder:
        return DavisDecoder(self.decoder_options())

    def words(self) -> np.ndarray:
        """The whole stream as little-endian 16-bit words (an odd trailing byte dropped)."""
        raw = b"".join(b for _, b in self.transfers)
        return np.frombuffer(raw[: len(raw) & ~1], "<u2")


class CaptureWriter:
    """Writes a capture: :meth:`add` each transfer as it arrives; :meth:`close` when done.

    ``path`` must not exist (a capture never overwrites a file).
    """

    def __init__(self, path, device: dict, registers: dict):
        self.path = Path(path)
        head = {"version": 1, "device": {k: device.get(k) for k in HEADER_DEVICE_FIELDS}, "registers": registers}
        blob = json.dumps(head, default=_jsonable).encode()
        self._fh = open(self.path, "xb")  # noqa: SIM115 - kept open for the records
        self._fh.write(MAGIC + struct.pack("<I", len(blob)) + blob)
        self.transfers = 0
        self.bytes = 0

    def add(self, t_ns: int, data: bytes) -> None:
        self._fh.write(_RECORD.pack(int(t_ns), len(data)))
        self._fh.write(data)
        self.transfers += 1
        self.bytes += len(data)

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


def _jsonable(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, tuple):
        return list(v)
    raise TypeError(f"{type(v).__name__} is not JSON serialisable")


def read_capture(path) -> Capture:
    """Read a capture written by :class:`CaptureWriter`.

    Raises
    ------
    CaptureError
        Not a capture (wrong magic), or a damaged header; a cut-short record list is not an error
        (``truncated``).
    """
    path = Path(path)
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise CaptureError(f"{path}: not a necviz DAVIS capture (it does not start with {MAGIC[:-1].decode()!r})")
    pos = len(MAGIC)
    try:
        (n,) = struct.unpack_from("<I", data, pos)
        head = json.loads(data[pos + 4 : pos + 4 + n].decode())
        device, registers = head["device"], head["registers"]
        device["dvs_size"], device["aps_size"]  # noqa: B018 - required keys
    except (struct.error, ValueError, KeyError, TypeError) as e:
        raise CaptureError(f"{path}: damaged capture header ({e})") from None
    pos += 4 + n
    cap = Capture(device, registers)
    while pos < len(data):
        if pos + _RECORD.size > len(data):
            cap.truncated = True
            break
        t_ns, size = _RECORD.unpack_from(data, pos)
        pos += _RECORD.size
        if pos + size > len(data):
            cap.truncated = True
            break
        cap.transfers.append((t_ns, data[pos : pos + size]))
        pos += size
    return cap


__all__ = ["Capture", "CaptureError", "CaptureWriter", "MAGIC", "read_capture"]
