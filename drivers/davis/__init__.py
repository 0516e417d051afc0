"""DAVIS cameras over USB (pyusb): driver, stream decoder and a device emulator.

* :func:`open_camera` → :class:`DavisCamera`, the live :class:`~necviz.drivers.source.Source`
  (``device="usb"`` for hardware, ``"emulated"`` for the virtual DAVIS346), streaming as its
  :class:`CameraOptions` say.
* :class:`DavisDecoder` (its stream format in :class:`DecoderOptions`) / :func:`decode_words`: the
  16-bit word stream → packets (Numba).
* :class:`StreamEncoder` (frames timed by :class:`FrameTiming`, laid out by :class:`StreamLayout`): packets →
  words (tests, emulator, benchmark).
* :class:`EmulatedDavis346` (set up by :class:`EmulatorOptions`, the camera it presents by
  :class:`CameraVariant`) / :class:`Faults`: a pyusb backend with a virtual DAVIS346.
* :class:`DavisDevice`, :func:`find_devices`, :func:`describe`: low-level device access.
"""

from necviz.drivers.davis.camera import DIGITAL_GAIN_MAX, CameraOptions, DavisCamera, open_camera
from necviz.drivers.davis.decoder import DavisDecoder, DecoderOptions
from necviz.drivers.davis.device import (
    BulkReader,
    DavisDevice,
    DeviceInfo,
    describe,
    find_devices,
    open_device,
    usb_backend,
)
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError, DeviceNotFoundError
from necviz.drivers.davis.emulator import CameraVariant, ControlRecord, EmulatedDavis346, EmulatorOptions, Faults
from necviz.drivers.davis.encoder import FrameTiming, StreamEncoder, StreamLayout, cds_pair

__all__ = [
    "BulkReader",
    "CameraVariant",
    "CameraOptions",
    "ControlRecord",
    "DIGITAL_GAIN_MAX",
    "DavisCamera",
    "DavisDecoder",
    "DecoderOptions",
    "DavisDevice",
    "DeviceDisconnectedError",
    "DeviceError",
    "DeviceInfo",
    "DeviceNotFoundError",
    "EmulatedDavis346",
    "EmulatorOptions",
    "Faults",
    "FrameTiming",
    "StreamEncoder",
    "StreamLayout",
    "cds_pair",
    "describe",
    "find_devices",
    "open_camera",
    "open_device",
    "usb_backend",
]
