"""Several bulk transfers in flight, as libcaer keeps them: the transfer ring of the DAVIS driver.

libcaer reads the data endpoint 0x82 with 8 transfers of 8 KiB (``src/davis.c``, ``davisOpenInternal``: the
transfer number and size it sets; ``src/usb_utils.c``, ``usbAllocateTransfers``: all of them submitted at once,
no timeout; ``usbDataTransferCallback``: the data of a completed transfer is handed on and the transfer submitted
again at once; ``usbThreadRun``: one thread does nothing but handle libusb's events). While the host handles one
transfer the next ones are already waiting on the endpoint, so the device never waits for the host between two
transfers, and small transfers end (full) after a fraction of a millisecond at the peak rate instead of holding
~10 ms as one 256 KiB read does (``benchmarks/transfers.py``).

Two backends, both delivering transfers in submission order into the queue of :class:`~.device.BulkReader`
(whose bound in sensor time, backpressure and drop accounting they keep: a reader whose queue is full stops
reading, and the device drops and counts whole events):

* ``libusb1`` (:class:`Libusb1Ring`, the ``libusb1`` package: ``pip install 'necviz[usb]'``): ``transfers``
  asynchronous transfers of ``transfer_size`` bytes submitted at once and each resubmitted as it completes, on one
  thread that handles libusb's events and decodes what completed (as libcaer's USB thread translates in its
  callback): while it decodes, the other transfers in flight keep the endpoint busy, and a second Python thread
  would only add waits for the interpreter lock. Completions are put back in submission order whatever order the
  callbacks come in.
* ``pyusb`` (:class:`PyusbRing`, when ``libusb1`` is not installed): pyusb has no asynchronous transfers, so one
  thread reads ``transfer_size`` bytes at a time into a ring of ``transfers`` buffers and a second thread decodes
  them; the read loop does nothing else, so the gap between two reads is a few µs of Python.

:func:`resolve_usb` picks one (``auto``: libusb1 if installed), :func:`parse_transfers` reads ``N,BYTES``.
"""

from __future__ import annotations

import array
import collections
import threading
import time

import usb.core

from necviz.core.errors import ParameterError
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.device import BulkReader, DavisDevice, _is_disconnect, thread_failed
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError

#: the USB library choices of ``necviz live --usb``
USB_CHOICES = ("auto", "libusb1", "pyusb")
#: transfers kept in flight: libcaer keeps 8 of 8 KiB (``davisOpenInternal`` in ``src/davis.c``; its host config
#: ``CAER_HOST_CONFIG_USB_BUFFER_NUMBER`` changes the count). necviz keeps 32 of libcaer's 8 KiB: a Python host
#: pauses for milliseconds (the interpreter lock, the garbage collector, a loaded machine) where libcaer's C thread
#: does not, and 8 x 8 KiB with the device's 128 KiB FIFO holds only ~4 ms at 12 Mev/s. 32 x 8 KiB buffers as much
#: as the old single 256 KiB read did while each transfer still ends after 8 KiB (the delay of libcaer's size):
#: on the emulator, a 50 ms consumer stall at 12 Mev/s on a loaded machine (tests/test_davis_load.py) dropped
#: events in 3 of 6 runs with 8 transfers, 1 of 3 with 16, 0 of 9 with 32
DEFAULT_TRANSFERS = 32
DEFAULT_TRANSFER_BYTES = 8 * 1024
#: the old single synchronous read (``CameraOptions(usb="single")``; kept for ``benchmarks/transfers.py``)
SINGLE_TRANSFER_BYTES = 256 * 1024
MAX_TRANSFERS = 64
#: a transfer is whole SuperSpeed bulk packets (1024 bytes; a buffer that ends inside a packet can overflow)
PACKET_BYTES = 1024
MAX_TRANSFER_BYTES = 4 * 1024 * 1024
INSTALL_HINT = "pip install 'necviz[usb]'"

# libusb's ``enum libusb_transfer_status`` (libusb.h), as the ``libusb1`` package's ``usb1.TRANSFER_*``
TRANSFER_COMPLETED = 0
TRANSFER_ERROR = 1
TRANSFER_TIMED_OUT = 2
TRANSFER_CANCELLED = 3
TRANSFER_STALL = 4
TRANSFER_NO_DEVICE = 5
TRANSFER_OVERFLOW = 6
STATUS_NAMES = {
    TRANSFER_COMPLETED: "completed",
    TRANSFER_ERROR: "error",
    TRANSFER_TIMED_OUT: "timed out",
    TRANSFER_CANCELLED: "cancelled",
    TRANSFER_STALL: "stalled",
    TRANSFER_NO_DEVICE: "no device",
    TRANSFER_OVERFLOW: "overflow",
}


def libusb1_version() -> str | None:
    """The installed ``libusb1`` package's version, None if it is not installed."""
    try:
        import usb1
    except (ImportError, OSError):  # OSError: the package is there, libusb-1.0 itself is not
        return None
    return str(getattr(usb1, "__version__", "?"))


def resolve_usb(choice: str) -> str:
    """``auto`` -> ``libusb1`` if installed, else ``pyusb``; ``libusb1`` without the package is refused in one
    line; ``pyusb`` and ``single`` (the old one-read reader) as given."""
    if choice not in USB_CHOICES + ("single",):
        raise ParameterError(f"usb must be one of {', '.join(USB_CHOICES)}, got {choice!r}")
    if choice == "auto":
        return "libusb1" if libusb1_version() is not None else "pyusb"
    if choice == "libusb1" and libusb1_version() is None:
        raise ParameterError(f"--usb libusb1 needs the libusb1 package: {INSTALL_HINT}")
    return choice


def check_transfers(n, size) -> tuple[int, int]:
    """``(transfers, bytes)`` validated: 1..64 transfers of 1 KiB..4 MiB, whole 1024-byte packets."""
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_TRANSFERS:
        raise ParameterError(f"transfers must be 1..{MAX_TRANSFERS}, got {n!r}")
    if (
        isinstance(size, bool)
        or not isinstance(size, int)
        or not PACKET_BYTES <= size <= MAX_TRANSFER_BYTES
        or size % PACKET_BYTES
    ):
        raise ParameterError(
            f"transfer size must be a multiple of {PACKET_BYTES} bytes, {PACKET_BYTES}..{MAX_TRANSFER_BYTES}, "
            f"got {size!r}"
        )
    return n, size


def parse_transfers(text: str) -> tuple[int, int]:
    """``"N,BYTES"`` (``BYTES`` may end in ``k``/``KiB``: 1024 bytes) -> ``(N, BYTES)``; nonsense refused in one line."""
    parts = str(text).replace(" ", "").split(",")
    bad = ParameterError(f"--usb-transfers takes N,BYTES (e.g. 8,8192 or 8,8k), got {text!r}")
    if len(parts) != 2:
        raise bad
    n_text, b_text = parts[0], parts[1].lower()
    scale = 1
    for suffix in ("kib", "k"):
        if b_text.endswith(suffix):
            b_text, scale = b_text[: -len(suffix)], 1024
            break
    try:
        n, size = int(n_text), int(b_text) * scale
    except ValueError:
        raise bad from None
    return check_transfers(n, size)


def usb_library_line() -> str:
    """One line for ``necviz devices``: how the driver reads the data endpoint (by default one 256 KiB pyusb read
    in flight; the rings on request)."""
    v = libusb1_version()
    ring = f"{DEFAULT_TRANSFERS} x {DEFAULT_TRANSFER_BYTES // 1024} KiB"
    single = f"USB library: pyusb, one {SINGLE_TRANSFER_BYTES // 1024} KiB read in flight (the default)"
    if v is not None:
        return f"{single}; libusb1 {v} installed: --usb libusb1 keeps {ring} asynchronous transfers in flight"
    return f"{single}; libusb1 not installed ({INSTALL_HINT}): --usb pyusb reads {ring} on a thread of its own"


class _Ring(BulkReader):
    """What both rings share: a USB thread puts transfers (``("data", bytes)``, or the item that ends the
    stream) in submission order into ``_ready``, and they are decoded and queued through
    :meth:`BulkReader._deliver` (the bound in sensor time): by this reader's own thread, at most ``transfers``
    waiting (:class:`PyusbRing`), or by the USB thread itself between event handling (:class:`Libusb1Ring`)."""

    library = "?"

    def __init__(
        self,
        device: DavisDevice,
        transfers: int = DEFAULT_TRANSFERS,
        transfer_size: int = DEFAULT_TRANSFER_BYTES,
        timeout_ms: int = 100,
        buffer_s: float = 2.0,
        max_queued: int | None = None,
        decode=None,
    ):
        super().__init__(device, transfer_size, timeout_ms, buffer_s, max_queued, decode)
        self.transfers = int(transfers)
        self._ready: collections.deque = collections.deque()
        self._ready_cv = threading.Condition()
        self.stats.update({"ring_full_s": 0.0, "out_of_order": 0, "cancelled": 0, "joined": 0})
        self.usb_thread = threading.Thread(target=self._usb_guard, name=f"necviz-usb-{device.serial}", daemon=True)

    def start(self) -> None:
        self.usb_thread.start()
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        with self._ready_cv:
            self._ready_cv.notify_all()
        with self._room:
            self._room.notify_all()
        me = threading.current_thread()
        for t in (self.usb_thread, self.thread):
            if t.is_alive() and t is not me:
                t.join(timeout=5.0)

    def _push(self, item) -> None:
        with self._ready_cv:
            self._ready.append(item)
            self._ready_cv.notify_all()

    def _ring_room(self) -> bool:
        return len(self._ready) < self.transfers

    def _wait_ring_room(self) -> bool:
        """Block the USB side until fewer than ``transfers`` transfers wait for the decoder; False if stopped."""
        with self._ready_cv:
            if not self._ring_room():
                t0 = time.monotonic()
                while not self._ring_room() and not self._stop.is_set():
                    self._ready_cv.wait(0.05)
                self.stats["ring_full_s"] += time.monotonic() - t0
            return not self._stop.is_set()

    def _usb_guard(self) -> None:
        try:
            self._usb_run()
        except DeviceError as e:  # opening the transfers failed: the stream ends with the reason
            self._end_with(("disconnected" if isinstance(e, DeviceDisconnectedError) else "error", e))
        except usb.core.USBError as e:
            self._end_with(("disconnected" if _is_disconnect(e) else "error", e))
        except Exception as e:  # not the device's: a bug ends the stream in one line, the consumer does not hang
            self._end_with(("error", thread_failed(e)))

    def _end_with(self, item) -> None:
        self._push(item)

    def _usb_run(self) -> None:  # pragma: no cover - each ring has its own
        raise NotImplementedError

    def _take_ready(self) -> tuple:
        """The next item of ``_ready``; data of transfers that completed back to back are joined into one
        ``("data", bytes, transfers)``: the decoder keeps its state across transfer boundaries, so decoding them
        at once gives the same stream, and the cost per decode call (~0.1 ms of Python) is paid once per burst
        instead of once per 8 KiB — at a frame's readout (360 KiB on a DAVIS346) that is 45 calls, enough to
        let the backlog grow on a loaded host. At most ``transfers`` are joined (one ring's worth)."""
        item = self._ready.popleft()
        if item[0] != "data" or not self._ready or self._ready[0][0] != "data":
            return (*item, 1) if item[0] == "data" else item
        parts = [item[1]]
        while self._ready and self._ready[0][0] == "data" and len(parts) < self.transfers:
            parts.append(self._ready.popleft()[1])
        self.stats["joined"] += len(parts) - 1
        return ("data", b"".join(parts), len(parts))

    def _run(self) -> None:
        """The decoding side: transfers in order, into the queue bounded in sensor time."""
        while True:
            with self._ready_cv:
                while not self._ready and not self._stop.is_set():
                    self._ready_cv.wait(0.05)
                if self._stop.is_set():
                    return
                item = self._take_ready()
                self._ready_cv.notify_all()
            if item[0] != "data":
                self.queue.put(item)  # the end of the stream, after everything read before it
                return
            if not self._deliver(item[1], len(item[1]), item[2]):
                return


class PyusbRing(_Ring):
    """The fallback without ``libusb1``: one thread of synchronous pyusb reads of ``transfer_size`` bytes (one in
    flight; pyusb cannot submit more without threads whose completions it could not order), a ring of
    ``transfers`` buffers between it and the decoding thread."""

    library = "pyusb"

    def _usb_run(self) -> None:
        buf = array.array("B", bytes(self.transfer_size))
        view = memoryview(buf)
        dev = self.device
        while self._wait_ring_room():
            try:
                n = dev.read(buf, self.timeout_ms)
            except usb.core.USBError as e:
                if self._stop.is_set():
                    return
                end = self._read_failed(e)
                if end is None:
                    continue
                self._push(end)
                return
            if n > 0:
                self._push(("data", bytes(view[:n])))


class Libusb1Ring(_Ring):
    """``transfers`` asynchronous bulk transfers of endpoint 0x82 kept in flight through ``libusb1``.

    ``opener`` (default :meth:`~.device.DavisDevice.open_libusb1`) returns ``(context, handle)``: a
    ``usb1.USBContext`` and ``usb1.USBDeviceHandle`` with the interface claimed, or the emulator's stand-ins
    (:mod:`.emulator_libusb1`). Each transfer is numbered when submitted; a completion is kept until every
    earlier one is in, so data reach the decoder in submission order whatever order the callbacks come in
    (``out_of_order`` counts the early ones). As libcaer's ``usbDataTransferCallback`` (``src/usb_utils.c``),
    data a transfer holds is kept whatever its status and a completed transfer is submitted again at once;
    unlike libcaer, transfers carry a timeout (``timeout_ms``) so the reader notices a finished emulated stream,
    and a timed-out transfer is resubmitted (its partial data kept). A stall cancels the transfers behind it,
    is cleared once every transfer is back, then all are submitted again (``stalls``; libcaer ends the stream); no device ends the stream as ``disconnected`` after the data
    of every earlier transfer; another status (error, overflow) as ``error`` with a one-line reason. At stop, the
    transfers are cancelled and their callbacks awaited (libcaer's ``usbCancelAndDeallocateTransfers``). Decoding runs
    on the same thread, between event handling; while the queue is full (the consumer ``buffer_s`` behind) it waits
    and completed transfers stay unsubmitted, so reading stops.
    """

    library = "libusb1"

    def start(self) -> None:
        self.usb_thread.start()  # one thread: the transfers in flight keep the endpoint busy while it decodes

    def _end_with(self, item) -> None:
        self.queue.put(item)  # no decoding thread to pass it on

    def _drain(self) -> bool:
        """Decode and queue what completed, in order, on the USB thread (libcaer translates in its USB thread's
        callback too): while this waits for room in the queue nothing is resubmitted, so reading stops and the
        device drops and counts. False when the stream has ended or the reader stopped."""
        while self._ready:
            item = self._take_ready()
            if item[0] != "data":
                self.queue.put(item)  # the end of the stream, after everything read before it
                return False
            if not self._deliver(item[1], len(item[1]), item[2]):
                return False
        return not self._stop.is_set()

    def __init__(self, device: DavisDevice, *args, opener=None, **kw):
        super().__init__(device, *args, **kw)
        self._opener = opener if opener is not None else device.open_libusb1
        self._results: dict[int, tuple] = {}
        self._seq_of: dict[int, int] = {}  # transfer index -> number it was submitted under
        self._next_seq = 0
        self._deliver_seq = 0
        self._active = 0
        self._parked: list = []  # transfers back and not yet resubmitted (ring full, stall being cleared)
        self._ended = False
        self._stall = False

    def _submit(self, t) -> bool:
        i = t.getUserData()
        self._seq_of[i] = self._next_seq
        self._next_seq += 1
        try:
            t.submit()
        except Exception as e:  # usb1.USBError: the device is gone or the handle closed
            self._finish_seq(self._seq_of[i], self._end_for(e))
            return False
        self._active += 1
        return True

    def _end_for(self, e: BaseException) -> tuple:
        if _is_disconnect(e) or "NO_DEVICE" in str(e) or "No such device" in str(e):
            return ("disconnected", e)
        return ("error", DeviceError(f"submitting a transfer failed: {e}"))

    def _callback(self, t) -> None:
        """libusb's completion callback (on the USB thread, inside ``handleEventsTimeout``)."""
        self._active -= 1
        seq = self._seq_of[t.getUserData()]
        status = t.getStatus()
        n = t.getActualLength()
        data = bytes(t.getBuffer()[:n]) if n > 0 else b""
        again = False
        if status == TRANSFER_COMPLETED:
            result: tuple = ("data", data)
            again = True
        elif status == TRANSFER_TIMED_OUT:
            self.stats["timeouts"] += 1
            if not n and getattr(self.device.backend, "stream_finished", False):
                result = ("finished", None)
            else:
                result = ("data", data)
                again = True
        elif status == TRANSFER_CANCELLED:
            self.stats["cancelled"] += 1
            result = ("data", data)  # data a cancelled transfer holds are kept (libcaer does)
            if self._stall:  # cancelled to clear a stall: submitted again once it is cleared
                again = True
            elif not self._stop.is_set():
                result = ("error", DeviceError("a transfer was cancelled while streaming"), data)
        elif status == TRANSFER_STALL:
            if not self._stall:
                self.stats["stalls"] += 1
            self._stall = True
            result = ("data", data)
            again = True  # after the halt is cleared
        elif status == TRANSFER_NO_DEVICE:
            result = ("disconnected", DeviceDisconnectedError("the device is gone (no device)"), data)
        else:
            name = STATUS_NAMES.get(status, f"status {status}")
            result = ("error", DeviceError(f"bulk transfer {seq} ended: {name}"), data)
        if seq != self._deliver_seq and not self._ended and status != TRANSFER_CANCELLED:
            self.stats["out_of_order"] += 1
        self._finish_seq(seq, result)
        if again and not self._stop.is_set() and not self._ended:
            self._parked.append(t)

    def _finish_seq(self, seq: int, result: tuple) -> None:
        """Record transfer ``seq``'s outcome and pass on, in order, every outcome now complete."""
        self._results[seq] = result
        while self._deliver_seq in self._results and not self._ended:
            r = self._results.pop(self._deliver_seq)
            self._deliver_seq += 1
            if r[0] == "data":
                if r[1]:
                    self._push(("data", r[1]))
                continue
            if len(r) > 2 and r[2]:  # the data the failing transfer held come first
                self._push(("data", r[2]))
            self._ended = True
            self._push((r[0], r[1]))
        if self._ended:
            self._results.clear()

    def _clear_stall(self, handle) -> None:
        try:
            handle.clearHalt(P.DATA_ENDPOINT)
        except Exception as e:  # usb1.USBError
            self._finish_seq(self._next_seq, self._end_for(e))
            self._next_seq += 1
        self._stall = False

    def _usb_run(self) -> None:
        context, handle = self._opener()
        xfers = []
        try:
            for i in range(self.transfers):
                t = handle.getTransfer()
                t.setBulk(
                    P.DATA_ENDPOINT, self.transfer_size, callback=self._callback, user_data=i, timeout=self.timeout_ms
                )
                xfers.append(t)
            stall_cancelled = False
            for t in xfers:  # all in flight at once, as libcaer's usbAllocateTransfers
                if not self._submit(t):
                    break
            while self._drain():
                if self._stall and self._active and not stall_cancelled:
                    stall_cancelled = True  # the transfers behind a stalled one: back before the halt is cleared
                    self._cancel_submitted(xfers)
                if self._parked and not (self._stall and self._active):
                    stall_cancelled = False
                    if self._stall:
                        self._clear_stall(handle)
                    while self._parked and not self._ended:
                        if not self._submit(self._parked.pop(0)):
                            break
                    continue  # a failed submission ended the stream: drain says so
                if self._active:
                    context.handleEventsTimeout(tv=0.01)
                elif not self._ended:
                    break  # nothing in flight, nothing to submit
        finally:
            self._cancel_all(context, xfers)
            for closing in (handle, context):
                try:
                    closing.close()
                except Exception:  # usb1.USBError on a vanished device: nothing left to release
                    pass

    def _cancel_all(self, context, xfers) -> None:
        """Cancel every transfer in flight and handle events until all callbacks came back (1 s at most)."""
        deadline = time.monotonic() + 1.0
        while self._active > 0 and time.monotonic() < deadline:
            self._cancel_submitted(xfers)
            context.handleEventsTimeout(tv=0.01)
        self._parked.clear()

    @staticmethod
    def _cancel_submitted(xfers) -> None:
        for t in xfers:
            if t.isSubmitted():
                try:
                    t.cancel()
                except Exception:  # usb1.USBErrorNotFound: it completed meanwhile
                    pass


def make_reader(device: DavisDevice, usb: str, transfers: int, transfer_size: int, **kw) -> BulkReader:
    """The reader for a resolved ``usb`` library (:func:`resolve_usb`): a ring, or the old single read."""
    if usb == "libusb1":
        return Libusb1Ring(device, transfers, transfer_size, **kw)
    if usb == "pyusb":
        return PyusbRing(device, transfers, transfer_size, **kw)
    return BulkReader(device, transfer_size, **kw)
