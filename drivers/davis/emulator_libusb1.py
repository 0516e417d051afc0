"""Stand-ins for the ``libusb1`` package's context, device handle and transfers, served by the emulated DAVIS346.

:meth:`EmulatedDavis346.open_libusb1 <necviz.drivers.davis.emulator.EmulatedDavis346.open_libusb1>` returns
``(EmulatedContext, EmulatedHandle)``, so :class:`~.transfers.Libusb1Ring` runs its own code on the emulator,
without the package or a camera. Only what the ring uses is there: ``handle.getTransfer()``,
``transfer.setBulk/submit/cancel/isSubmitted/getStatus/getActualLength/getBuffer/getUserData``,
``handle.clearHalt``, ``context.handleEventsTimeout`` and ``close``.

The endpoint fills submitted transfers one after another, in submission order, through the device model's bulk
read (:mod:`.emulator_stream`: its pacing, FIFO, early packet and faults): a read that times out completes
the transfer as timed out, a stall (EPIPE) as stalled, an unplug (ENODEV) as no device, any other error as
error. While a transfer is read, the room of the transfers queued behind it (and its own) counts as buffering
beside the device's FIFO (``host_buffer_bytes``): data produced while the host was away wait in them, as on a
camera with transfers in flight, instead of overflowing the FIFO. The callbacks fire from ``handleEventsTimeout`` on the caller's thread, as libusb's do. For tests,
``reorder=k`` holds up to ``k`` filled transfers and fires their callbacks in reverse order (libusb gives no
order guarantee across callbacks the ring relies on), and ``inject`` maps a transfer's submission number to
a status it completes with instead of being read (e.g. an overflow).
"""

from __future__ import annotations

import errno
import time

import usb.core

from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.transfers import (
    TRANSFER_CANCELLED,
    TRANSFER_COMPLETED,
    TRANSFER_ERROR,
    TRANSFER_NO_DEVICE,
    TRANSFER_STALL,
    TRANSFER_TIMED_OUT,
)


class TransferNotFound(Exception):
    """Cancelling a transfer that is not in flight (``usb1.USBErrorNotFound``)."""


class EmulatedTransfer:
    """One bulk transfer (``usb1.USBTransfer``'s methods the ring uses)."""

    def __init__(self, handle: EmulatedHandle):
        self._handle = handle
        self._buffer = bytearray()
        self._callback = None
        self._user_data = None
        self._timeout_ms = 0
        self._endpoint = P.DATA_ENDPOINT
        self._submitted = False
        self._status = TRANSFER_COMPLETED
        self._length = 0
        self._seq = -1  # the number it was last submitted under
        self.submissions = 0

    def setBulk(self, endpoint, buffer_or_len, callback=None, user_data=None, timeout=0):  # noqa: N802
        if self._submitted:
            raise ValueError("cannot alter a submitted transfer")
        self._endpoint = endpoint
        self._buffer = bytearray(buffer_or_len) if isinstance(buffer_or_len, int) else bytearray(buffer_or_len)
        self._callback, self._user_data, self._timeout_ms = callback, user_data, timeout

    def submit(self) -> None:
        if self._submitted:
            raise ValueError("transfer already submitted")
        self._handle._submit(self)

    def cancel(self) -> None:
        if not self._submitted:
            raise TransferNotFound("LIBUSB_ERROR_NOT_FOUND")
        self._handle._cancel(self)

    def isSubmitted(self) -> bool:  # noqa: N802
        return self._submitted

    def getStatus(self) -> int:  # noqa: N802
        return self._status

    def getActualLength(self) -> int:  # noqa: N802
        return self._length

    def getBuffer(self):  # noqa: N802
        return memoryview(self._buffer)

    def getUserData(self):  # noqa: N802
        return self._user_data


class EmulatedHandle:
    """A device handle (``usb1.USBDeviceHandle``) on an emulated DAVIS346, its interface claimed."""

    def __init__(self, device, reorder: int = 1, inject: dict[int, int] | None = None):
        self.device = device
        self.reorder = max(1, int(reorder))
        self.inject = dict(inject or {})
        self._queue: list[EmulatedTransfer] = []  # in flight, in submission order
        self._done: list[EmulatedTransfer] = []  # filled, callbacks not yet fired
        self._cancelled: list[EmulatedTransfer] = []
        self.submitted = 0  # submission number of the next transfer
        self.completions: list[tuple[object, int]] = []  # (user data, status) in callback order
        self.closed = False

    def getTransfer(self, iso_packets: int = 0) -> EmulatedTransfer:  # noqa: N802
        return EmulatedTransfer(self)

    def clearHalt(self, endpoint: int) -> None:  # noqa: N802
        self.device.clear_halt(None, endpoint)

    def claimInterface(self, interface: int) -> None:  # noqa: N802
        self.device.claim_interface(None, interface)

    def close(self) -> None:
        self.closed = True

    def _submit(self, t: EmulatedTransfer) -> None:
        if self.closed:
            raise usb.core.USBError("handle closed", errno=errno.EBADF)
        t._submitted = True
        t._seq = self.submitted
        self.submitted += 1
        t.submissions += 1
        self._queue.append(t)

    def _cancel(self, t: EmulatedTransfer) -> None:
        if t in self._queue:
            self._queue.remove(t)
            t._status, t._length = TRANSFER_CANCELLED, 0
            self._cancelled.append(t)

    def _fill(self, t: EmulatedTransfer) -> None:
        """The endpoint serves ``t``: one bulk read of the device model into its buffer."""
        injected = self.inject.pop(t._seq, None)
        if injected is not None:
            t._status, t._length = injected, 0
            return
        # the transfers in flight: while the host was away, data flowed into this one and those queued behind it,
        # not only into the device's FIFO
        self.device.host_buffer_bytes = len(t._buffer) + sum(len(q._buffer) for q in self._queue)
        try:
            n = self.device.bulk_read(None, t._endpoint, P.INTERFACE, t._buffer, t._timeout_ms or 1000)
            t._status, t._length = TRANSFER_COMPLETED, int(n)
        except usb.core.USBTimeoutError:
            t._status, t._length = TRANSFER_TIMED_OUT, 0
        except usb.core.USBError as e:
            code = getattr(e, "errno", None)
            status = {errno.EPIPE: TRANSFER_STALL, errno.ENODEV: TRANSFER_NO_DEVICE}.get(code or 0, TRANSFER_ERROR)
            t._status, t._length = status, 0
        finally:
            self.device.host_buffer_bytes = 0

    def _fire(self, t: EmulatedTransfer) -> None:
        t._submitted = False
        self.completions.append((t._user_data, t._status))
        if t._callback is not None:
            t._callback(t)

    def handle_events(self, tv: float) -> None:
        """Complete what the endpoint serves now: cancelled transfers first, then the oldest in flight (up to
        ``reorder`` of them, fired in reverse)."""
        if self._cancelled:
            cancelled, self._cancelled = self._cancelled, []
            for t in cancelled:
                self._fire(t)
            return
        if not self._queue and not self._done:
            time.sleep(tv)
            return
        burst: list[EmulatedTransfer] = []
        if self._queue:
            t = self._queue.pop(0)
            self._fill(t)
            self._done.append(t)
            ending = t._status != TRANSFER_COMPLETED
            if len(self._done) < self.reorder and self._queue and not ending:
                return
            if not ending and self.reorder == 1:
                burst = self._fill_waiting(t)
        done, self._done = self._done, []
        for t in reversed(done):
            self._fire(t)
        for t in burst:
            self._fire(t)

    def _fill_waiting(self, t: EmulatedTransfer) -> list[EmulatedTransfer]:
        """After ``t`` ended full, the transfers waiting behind it that the device's FIFO can fill whole, filled
        at once (in submission order), as a camera fills them at bus speed and libusb reports every completion
        in one round of event handling: the emulator does not make the host pay one event round (a device read,
        the sensor's simulation) per transfer for data already waiting."""
        burst: list[EmulatedTransfer] = []
        while (
            t._status == TRANSFER_COMPLETED
            and t._length == len(t._buffer)
            and self._queue
            and self._queue[0]._seq not in self.inject
        ):
            t = self._queue[0]
            n = self.device.take_full(t._buffer)
            if not n:
                break
            self._queue.pop(0)
            t._status, t._length = TRANSFER_COMPLETED, n
            burst.append(t)
        return burst


class EmulatedContext:
    """A libusb context (``usb1.USBContext``) whose event handling serves one :class:`EmulatedHandle`."""

    def __init__(self, handle: EmulatedHandle):
        self.handle = handle

    def handleEventsTimeout(self, tv: float = 0) -> None:  # noqa: N802
        self.handle.handle_events(float(tv or 0))

    def close(self) -> None:
        pass
