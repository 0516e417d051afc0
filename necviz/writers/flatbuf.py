"""The few FlatBuffers an AEDAT 4 file holds, laid out with NumPy (no per-element Python).

FlatBuffers (https://flatbuffers.dev/internals/) is a binary layout, not a library: a buffer starts
with a ``uint32`` offset to its root table (optionally preceded by a ``uint32`` size, "size-prefixed",
and followed by a 4-character file identifier); a table starts with an ``int32`` *soffset* back to
its *vtable* (``uint16`` vtable size, ``uint16`` table size, one ``uint16`` field offset per slot,
0 = absent), then its inline fields; a vector is a ``uint32`` count followed by its elements; a
string is a vector of bytes with a terminating NUL; every reference (``uoffset``) is unsigned and
counted from where it is stored, so what it points to lies *after* it. Scalars are little-endian and
aligned to their size, counted from the start of the buffer (the size prefix included).

Builders usually write back to front; this module writes front to back, which the rules above
allow, so a packet of N events is one NumPy copy. Only what the AEDAT 4 schemas need is here:
tables of scalars and references, vectors of structs, vectors of identical tables (one shared
vtable), strings.
"""

from __future__ import annotations

import struct

import numpy as np

_SIZE = {"q": 8, "d": 8, "i": 4, "I": 4, "f": 4, "h": 2, "H": 2, "b": 1, "B": 1, "?": 1, "O": 4}


class Buffer:
    """One FlatBuffer under construction, written front to back.

    Parameters
    ----------
    identifier : the 4-character file identifier (``b"EVTS"``).
    size_prefixed : start with the buffer's size (AEDAT 4 packets and data table), or not (the IOHeader).
    """

    def __init__(self, identifier: bytes, size_prefixed: bool = True):
        if len(identifier) != 4:
            raise ValueError("a FlatBuffers file identifier has 4 bytes")
        self.prefixed = size_prefixed
        self.buf = bytearray(b"\0\0\0\0" if size_prefixed else b"")
        self._root_at = len(self.buf)
        self.buf += b"\0\0\0\0" + identifier
        self._patches: list[tuple[int, str]] = []  # (position of a uoffset, name of its target)
        self._targets: dict[str, int] = {}

    # -- low level --------------------------------------------------------------------------------
    def pad(self, align: int, extra: int = 0) -> None:
        """Pad so that ``len + extra`` is a multiple of ``align``."""
        self.buf += b"\0" * ((-(len(self.buf) + extra)) % align)

    def here(self, name: str) -> int:
        """Name the current position as the target of references called ``name``."""
        self._targets[name] = len(self.buf)
        return len(self.buf)

    # -- objects ----------------------------------------------------------------------------------
    def table(self, fields: dict[int, tuple[str, object]], name: str | None = None, root: bool = False) -> int:
        """Write a vtable and its table; returns the table's position.

        ``fields`` maps slot -> ``(format, value)``: a :mod:`struct` scalar format (``q i h b f ?``), a
        struct as ``("8s", bytes)`` (aligned to 4), or ``("O", target name)`` for a reference to an object
        written later under that name (:meth:`here`). The largest fields come first, so aligning the table
        start aligns them all.
        """
        nslots = max(fields) + 1 if fields else 0
        order = sorted(fields.items(), key=lambda kv: -self._size(kv[1][0]))
        offsets, cursor = {}, 4
        for slot, (fmt, _) in order:
            size = self._size(fmt)
            cursor += (-(cursor + 4)) % min(size if fmt[-1] != "s" else 4, 8)  # the table starts at 4 mod 8
            offsets[slot] = cursor
            cursor += size
        tsize = cursor
        self.pad(2)
        vt = len(self.buf)
        self.buf += struct.pack(f"<HH{nslots}H", 4 + 2 * nslots, tsize, *(offsets.get(s, 0) for s in range(nslots)))
        self.pad(8, 4)  # table start = 4 mod 8: its first (8-byte) field lands on a multiple of 8
        pos = len(self.buf)
        self.buf += b"\0" * tsize
        struct.pack_into("<i", self.buf, pos, pos - vt)
        for slot, (fmt, value) in fields.items():
            at = pos + offsets[slot]
            if fmt == "O":
                self._patches.append((at, str(value)))
            elif fmt[-1] == "s":
                self.buf[at : at + len(value)] = value
            else:
                struct.pack_into("<" + fmt, self.buf, at, value)
        if name is not None:
            self._targets[name] = pos
        if root:
            self._targets["__root__"] = pos
        return pos

    @staticmethod
    def _size(fmt: str) -> int:
        return int(fmt[:-1]) if fmt[-1] == "s" else _SIZE[fmt]

    def vector(self, name: str, data: bytes | np.ndarray, count: int, align: int = 4) -> int:
        """A vector of ``count`` inline elements (scalars or structs) whose bytes are ``data``."""
        self.pad(max(align, 4), 4)
        pos = self.here(name)
        self.buf += struct.pack("<I", count)
        self.buf += memoryview(np.ascontiguousarray(data)).cast("B") if isinstance(data, np.ndarray) else data
        return pos

    def string(self, name: str, text: str) -> int:
        raw = text.encode("utf-8")
        self.pad(4)
        pos = self.here(name)
        self.buf += struct.pack("<I", len(raw)) + raw + b"\0"
        return pos

    def table_vector(self, name: str, records: np.ndarray, slots: dict[int, str]) -> int:
        """A vector of ``len(records)`` tables of one shape, sharing one vtable.

        ``records`` is a structured array whose first field is the ``int32`` soffset (filled in here)
        and whose other fields are the tables' fields at their byte offsets; its itemsize must keep
        every table start at 4 mod 8 (a multiple of 8). ``slots`` maps slot -> field name.
        """
        n = len(records)
        if records.dtype.itemsize % 8:
            raise ValueError("table records must be a multiple of 8 bytes")
        self.pad(4)
        vec = self.here(name)
        self.buf += struct.pack("<I", n)
        refs_at = len(self.buf)
        self.buf += b"\0" * (4 * n)
        nslots = max(slots) + 1
        field_off = {s: records.dtype.fields[f][1] for s, f in slots.items()}
        self.pad(2)
        vt = len(self.buf)
        self.buf += struct.pack(
            f"<HH{nslots}H", 4 + 2 * nslots, records.dtype.itemsize, *(field_off.get(s, 0) for s in range(nslots))
        )
        self.pad(8, 4)
        start = len(self.buf)
        pos = start + records.dtype.itemsize * np.arange(n, dtype=np.int64)
        recs = np.array(records, copy=True)
        recs[recs.dtype.names[0]] = (pos - vt).astype(np.int32)
        refs = (pos - (refs_at + 4 * np.arange(n, dtype=np.int64))).astype("<u4")
        self.buf[refs_at : refs_at + 4 * n] = refs.tobytes()
        self.buf += recs.tobytes()
        return vec

    # -- end --------------------------------------------------------------------------------------
    def finish(self) -> bytes:
        """Resolve the references and return the bytes (size prefix included when asked)."""
        root = self._targets["__root__"]
        struct.pack_into("<I", self.buf, self._root_at, root - self._root_at)
        for at, name in self._patches:
            struct.pack_into("<I", self.buf, at, self._targets[name] - at)
        self.pad(8)
        if self.prefixed:
            struct.pack_into("<I", self.buf, 0, len(self.buf) - 4)
        return bytes(self.buf)


__all__ = ["Buffer"]
