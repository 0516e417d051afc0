"""``necviz devices``: the DAVIS cameras attached (through necviz's driver and through dv-processing) and
the emulated one; ``--check``: what one camera actually sends (:mod:`necviz.drivers.davis.check`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.core.errors import NecvizError, ParameterError
from necviz.progress import output

if TYPE_CHECKING:
    from necviz.drivers.davis.device import DeviceInfo

#: the commands a listed camera is used with, by backend
_USE = {"usb": "--device usb", "dv": "--device dv", "emulated": "--device emulated"}


def list_devices(include_emulated: bool = True) -> list[DeviceInfo]:
    """Attached DAVIS FX3/FX2 cameras through libusb (necviz's driver), the DAVIS cameras dv-processing finds
    (if it is installed), then the emulated DAVIS346 if asked.

    Cameras that cannot be opened (permission denied, old firmware) are listed with ``error`` set.
    If libusb itself is missing, no camera is listed through it.
    """
    from necviz.drivers.davis.device import describe, usb_backend
    from necviz.drivers.dv_camera import find_dv_cameras

    out: list[DeviceInfo] = []
    try:
        out += describe(usb_backend())
    except NecvizError:
        pass
    out += find_dv_cameras()
    if include_emulated:
        from necviz.drivers.davis.emulator import EmulatedDavis346

        out += describe(EmulatedDavis346(), emulated=True)
    return out


def run(include_emulated: bool = True, out=...) -> int:
    """Print the cameras found and what to do with them; 0 if a usable camera was listed, else 1."""
    from necviz.drivers.davis import protocol as P
    from necviz.drivers.davis.device import usb_backend

    out = output(out)
    try:
        usb_backend()
        libusb_error = ""
    except NecvizError as e:
        libusb_error = str(e).splitlines()[0]
    try:
        import dv_processing  # noqa: F401

        dv_missing = False
    except ImportError:
        dv_missing = True
    devices = list_devices(include_emulated)
    from necviz.drivers.davis.transfers import usb_library_line

    print(usb_library_line(), file=out)
    if devices:
        print(f"{'backend':9s} {'kind':10s} {'serial':10s} {'firmware':>8s} {'logic':>6s}  where / status", file=out)
    for d in devices:
        logic = "-" if d.logic is None else str(d.logic)
        status = d.where + (f"  (cannot be used: {d.error})" if d.error else "")
        print(f"{d.backend:9s} {d.kind:10s} {d.serial:10s} {d.firmware:8d} {logic:>6s}  {status}", file=out)
        for note in d.notes:
            print(f"{'':9s} note: {note}", file=out)
    real = [d for d in devices if d.backend != "emulated"]
    usable = [d for d in devices if d.usable]
    emulated = any(d.backend == "emulated" for d in usable)
    cameras = sorted({d.serial for d in real if d.usable})
    found = []
    if cameras:
        uses = {s: " or ".join(_USE[d.backend] for d in real if d.serial == s and d.usable) for s in cameras}
        found.append(
            f"{len(cameras)} DAVIS camera{'s' if len(cameras) > 1 else ''}: "
            + ", ".join(f"{s} (necviz live {uses[s]})" for s in cameras)
        )
    if emulated:
        found.append("the emulated DAVIS346 (necviz live --device emulated), necviz's driver on a virtual camera")
    print("found " + " and ".join(found) if found else "found no usable camera", file=out)
    if not cameras:
        why = f" ({libusb_error})" if libusb_error else ""
        if [d for d in real if not d.usable]:
            print("a DAVIS camera is attached but cannot be used: see its status above", file=out)
        else:
            print(f"no DAVIS camera is attached (USB 152a:841a / 152a:841b){why}", file=out)
        print("if one is plugged in, " + P.UDEV_HINT, file=out)
    if dv_missing:
        print("the dv backend (--device dv) needs iniVation's dv-processing: pip install 'necviz[dv]'", file=out)
    return 0 if usable else 1


def check(
    device: str = "usb",
    serial: str | None = None,
    capture_path=None,
    seconds: float | None = None,
    *,
    backend=None,
    out=...,
) -> int:
    """``necviz devices --check``: open the camera, record ``seconds`` of its raw stream (to ``capture_path`` if
    given) and print what it held with a verdict; 0 unless the verdict is FAIL.

    Parameters
    ----------
    device : str
        ``usb`` (a real camera through necviz's driver) or ``emulated`` (the virtual DAVIS346, paced in real
        time as a camera is).
    serial : str, optional
        Which camera when several are attached.
    capture_path : path, optional
        Write every transfer to this new file (:mod:`necviz.drivers.davis.capture`); it must not exist.
    seconds : float, optional
        How long to record (default :data:`~necviz.drivers.davis.check.CHECK_SECONDS`).
    backend : optional
        A pyusb backend to find the camera on (the tests pass a small emulated one).

    Raises
    ------
    ParameterError
        An unknown device, a bad duration, or a capture file that exists already.
    DeviceError
        No camera, old firmware, permission denied, unplugged during the check.
    """
    from pathlib import Path

    from necviz.drivers.davis.check import CHECK_SECONDS, analyse, capture, report_lines
    from necviz.drivers.davis.device import open_device, usb_backend

    out = output(out)
    if device not in ("usb", "emulated"):
        raise ParameterError(f"--check runs on --device usb or emulated, got {device!r}")
    seconds = CHECK_SECONDS if seconds is None else float(seconds)
    if not 0 < seconds <= 60:
        raise ParameterError(f"--seconds must be in (0, 60], got {seconds:g}")
    if capture_path is not None and Path(capture_path).exists():
        raise ParameterError(f"--capture {capture_path} exists already: a capture never replaces a file")
    if backend is None:
        if device == "emulated":
            from necviz.drivers.davis.emulator import EmulatedDavis346, EmulatorOptions

            backend = EmulatedDavis346(EmulatorOptions(realtime=True))
        else:
            backend = usb_backend()
    dev = open_device(backend, serial, emulated=device == "emulated")
    dev.warm_up()  # an emulator's simulator compiles before it can keep real time
    try:
        print(f"  checking {dev.kind} {dev.serial}: recording {seconds:g} s of its stream ...", file=out)
        cap = capture(dev, seconds, capture_path)
    finally:
        dev.close()
    report = analyse(cap)
    for line in report_lines(report, capture_path):
        print(line, file=out)
    return 1 if report.level == "FAIL" else 0


def add_arguments(p) -> None:
    from necviz.flags import number

    p.add_argument("--no-emulated", action="store_true", help="list real cameras only")
    p.add_argument("--check", action="store_true", help="record and judge one camera's stream")
    p.add_argument(
        "--device",
        choices=("usb", "emulated"),
        default="usb",
        help="with --check: usb (default, a real camera) or emulated",
    )
    p.add_argument("--serial", default=None, help="with --check: which camera when several are attached")
    p.add_argument(
        "--capture", metavar="FILE", default=None, help="with --check: keep the raw stream in FILE (a new file)"
    )
    p.add_argument(
        "--seconds",
        type=number("--seconds", "devices"),
        default=None,
        metavar="S",
        help="with --check: how long to record (default 2)",
    )


def _command(args) -> int:

    if args.check:
        return check(args.device, args.serial, args.capture, args.seconds)
    if args.capture is not None or args.seconds is not None:
        from necviz.core.errors import ParameterError

        raise ParameterError("--capture and --seconds go with --check")
    return run(include_emulated=not args.no_emulated)


COMMAND = Command(
    name="devices",
    help="attached (and emulated) DAVIS cameras: serial, firmware, logic version; --check: what one sends",
    description="Lists the DAVIS cameras found through necviz's driver and through dv-processing, and the "
    "emulated one. --check records a camera's raw stream for a few seconds and says what it held "
    "(events, frames, exposure echoes, the first frame's words, transfer timing) with a verdict.",
    add_arguments=add_arguments,
    run=_command,
)
