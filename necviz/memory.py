"""Keep a long session's resident memory from ratcheting up after bursts of events.

A lighting step makes the sensor fire a burst: for a fraction of a second every stage (the
simulated sensor, the USB transfers, the decoder, the sink's event window) holds arrays of tens of
MB. glibc's ``malloc`` serves a block that large with its own ``mmap`` and unmaps it when it is
freed, but it also raises its *mmap threshold* to the freed block's size (up to 32 MB), so the next
bursts are carved from the heap instead. Heap memory is only given back from the top, and the
long-lived objects allocated between two bursts pin what lies below them: each burst leaves
10–25 MB resident for the rest of the session (measured in ``benchmarks/soak.py``; see the README's
"Long live sessions: memory").

Fixing the threshold turns that adaptation off (glibc ``mallopt(3)``: setting ``M_MMAP_THRESHOLD``
or ``M_TRIM_THRESHOLD`` disables the dynamic adjustment of both). Blocks of at least
:data:`MMAP_THRESHOLD_BYTES` always get their own mapping and go back to the operating system when
freed; smaller ones (a frame is 0.7 MB as float64) stay on the heap, where they are reused without a
system call. Other C libraries (musl, macOS, Windows) are left as they are.
"""

from __future__ import annotations

import ctypes
import sys

#: blocks of this size or more get their own mapping, returned to the OS when freed
MMAP_THRESHOLD_BYTES = 4 << 20
#: free memory at the top of the heap beyond this is returned to the OS
TRIM_THRESHOLD_BYTES = 4 << 20

# glibc's mallopt parameter numbers (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

_applied: bool | None = None


def _glibc():
    """The process's glibc, or None if the C library is another one."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)
        version = libc.gnu_get_libc_version
    except (OSError, AttributeError):
        return None
    version.restype = ctypes.c_char_p
    return libc if version() else None


def bound_heap_retention() -> bool:
    """Fix glibc's mmap and trim thresholds so freed bursts go back to the OS.

    Process-wide and idempotent; called once by every dashboard session (``live``, ``replay``,
    ``demo``). Returns True if the thresholds are set (glibc), False where the C library is another.
    """
    global _applied
    if _applied is None:
        libc = _glibc()
        _applied = bool(
            libc is not None
            and libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
            and libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
        )
    return _applied
