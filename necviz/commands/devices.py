"""``necviz devices``: the DAVIS cameras attached (and the emulated one), with serial and versions."""

from __future__ import annotations

from necviz.core.errors import NecvizError
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.device import DeviceInfo, describe, usb_backend
from necviz.progress import output


def list_devices(include_emulated: bool = True) -> list[DeviceInfo]:
    """Attached DAVIS FX3/FX2 cameras (through libusb), then the emulated DAVIS346 if asked.

    Cameras that cannot be opened (permission denied, wrong firmware) are listed with ``error`` set.
    If libusb itself is missing, only the emulated camera is listed.
    """
    out: list[DeviceInfo] = []
    try:
        out += describe(usb_backend())
    except NecvizError:
        pass
    if include_emulated:
        from necviz.drivers.davis.emulator import EmulatedDavis346

        out += describe(EmulatedDavis346(), emulated=True)
    return out


def run(include_emulated: bool = True, out=...) -> int:
    """Print the table; return 0 if a real camera is usable, 1 if none is (the hint is printed)."""
    out = output(out)
    try:
        usb_backend()
        libusb_error = ""
    except NecvizError as e:
        libusb_error = str(e)
    devices = list_devices(include_emulated)
    print(f"{'kind':10s} {'serial':10s} {'firmware':>8s} {'logic':>6s}  where / status", file=out)
    for d in devices:
        logic = "-" if d.logic is None else str(d.logic)
        status = d.where + (f"  ({d.error})" if d.error else "")
        print(f"{d.kind:10s} {d.serial:10s} {d.firmware:8d} {logic:>6s}  {status}", file=out)
    usable = [d for d in devices if not d.emulated and not d.error]
    if not usable:
        if libusb_error:
            print(f"no DAVIS camera can be found: {libusb_error}", file=out)
        elif not [d for d in devices if not d.emulated]:
            print("no DAVIS camera found (USB 152a:841a / 152a:841b)", file=out)
        print(P.UDEV_HINT, file=out)
        print("`necviz live --device emulated` runs the same driver on a virtual DAVIS346", file=out)
        return 1
    return 0
