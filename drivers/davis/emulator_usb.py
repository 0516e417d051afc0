"""The USB surface of the emulated DAVIS346: enumeration, descriptors, device handles, control transfers.

:class:`UsbInterfaceMixin` holds the pyusb ``IBackend`` methods of
:class:`~necviz.drivers.davis.emulator.EmulatedDavis346` other than the bulk data reads (those are in
:mod:`.emulator_stream`): it presents one DAVIS FX3 (device with ``bcdDevice & 0xFF`` = firmware,
configuration 1, interface 0 with the interrupt endpoint 0x81 and the bulk endpoint 0x82, the
serial-number string), opens and claims it, and turns the vendor requests 0xBF (read/write one
register) and 0xC2 (write several) into register reads and writes of the device model, each logged as
a :class:`ControlRecord`. The interrupt endpoint never delivers data (its reads time out). Every call
fails with ENODEV while the device is unplugged (the device model's ``_check_plug``).
"""

from __future__ import annotations

import array
import errno
import time
from dataclasses import dataclass

import usb.core

from necviz.drivers.davis import protocol as P


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


class UsbInterfaceMixin:
    """The enumeration, descriptor, handle and control-transfer methods of
    :class:`~necviz.drivers.davis.emulator.EmulatedDavis346` (a mixin: it uses the device model's
    ``lock``, ``faults``, ``serial``, ``bus``/``address``, ``_check_plug``, ``_log``, ``_read`` and
    ``_write``)."""

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
        return _Desc(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0300,
            bDeviceClass=0,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=9,
            idVendor=P.VID,
            idProduct=P.PID_FX3,
            bcdDevice=0x0100 | (self.faults.firmware & 0xFF),
            iManufacturer=1,
            iProduct=2,
            iSerialNumber=3,
            bNumConfigurations=1,
            address=self.address,
            bus=self.bus,
            port_number=1,
            port_numbers=(1,),
            speed=4,
        )

    def get_configuration_descriptor(self, dev, config):
        return _Desc(
            bLength=9,
            bDescriptorType=2,
            wTotalLength=32,
            bNumInterfaces=1,
            bConfigurationValue=P.CONFIGURATION,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=50,
        )

    def get_interface_descriptor(self, dev, intf, alt, config):
        return _Desc(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=P.INTERFACE,
            bAlternateSetting=0,
            bNumEndpoints=2,
            bInterfaceClass=0xFF,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
        )

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if ep == 0:
            return _Desc(
                bLength=7,
                bDescriptorType=5,
                bEndpointAddress=P.DEBUG_ENDPOINT,
                bmAttributes=3,
                wMaxPacketSize=64,
                bInterval=1,
                bRefresh=0,
                bSynchAddress=0,
            )
        return _Desc(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=P.DATA_ENDPOINT,
            bmAttributes=2,
            wMaxPacketSize=1024,
            bInterval=0,
            bRefresh=0,
            bSynchAddress=0,
        )

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

    # -- interrupt endpoint (never delivers data) ----------------------------------------------------
    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        self._check_plug()
        time.sleep(min((timeout or 1000) / 1000.0, 0.01))
        raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)
