"""A small CDR (XCDR1, little endian) encoder and decoder for ROS 2 messages.

ROS 2 serializes messages as plain CDR: a 4-byte encapsulation header (``00 01 00 00`` for
little-endian CDR) followed by the fields in declaration order, each primitive aligned to its
own size (at most 8) counted from the end of the header. Strings are a uint32 length that counts
the terminating NUL, the bytes, then the NUL. Sequences are a uint32 element count followed by
the elements.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

from nehmo_core.errors import NehmoError

#: Encapsulation header of little-endian plain CDR, the representation ROS 2 uses.
CDR_LE_HEADER = b"\x00\x01\x00\x00"

_PRIMITIVES: dict[str, tuple[str, int]] = {
    "bool": ("?", 1),
    "byte": ("B", 1),
    "uint8": ("B", 1),
    "int8": ("b", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}

PRIMITIVE_TYPES = frozenset(_PRIMITIVES)


class CdrError(NehmoError):
    """A CDR buffer that is truncated, malformed or not little-endian plain CDR."""


class CdrWriter:
    """Appends CDR-encoded values to a growing buffer (which starts with the header)."""

    def __init__(self) -> None:
        self._buf = bytearray(CDR_LE_HEADER)

    def _align(self, size: int) -> None:
        pad = -(len(self._buf) - len(CDR_LE_HEADER)) % size
        if pad:
            self._buf.extend(b"\x00" * pad)

    def primitive(self, kind: str, value: object) -> None:
        """Write one primitive of ROS type `kind` (e.g. "float64", "uint32")."""
        code, size = _PRIMITIVES[kind]
        self._align(size)
        self._buf.extend(struct.pack("<" + code, value))

    def primitives(self, kind: str, values: Iterable[object]) -> None:
        """Write a sequence of primitives: count, then the elements (aligned if any)."""
        items = list(values)
        code, size = _PRIMITIVES[kind]
        self.primitive("uint32", len(items))
        if items:
            self._align(size)
            self._buf.extend(struct.pack(f"<{len(items)}{code}", *items))

    def string(self, value: str) -> None:
        """Write a string: uint32 length including the NUL, UTF-8 bytes, NUL."""
        data = value.encode("utf-8")
        self.primitive("uint32", len(data) + 1)
        self._buf.extend(data)
        self._buf.append(0)

    def strings(self, values: Iterable[str]) -> None:
        """Write a sequence of strings."""
        items = list(values)
        self.primitive("uint32", len(items))
        for item in items:
            self.string(item)

    def count(self, n: int) -> None:
        """Write the element count of a sequence of structures."""
        self.primitive("uint32", n)

    def getvalue(self) -> bytes:
        """The encoded message, header included."""
        return bytes(self._buf)


class CdrReader:
    """Reads CDR-encoded values from a buffer that starts with the encapsulation header."""

    def __init__(self, data: bytes | bytearray | memoryview) -> None:
        self._data = memoryview(data).cast("B")
        if len(self._data) < len(CDR_LE_HEADER):
            raise CdrError(f"CDR buffer too short for its header: {len(self._data)} bytes")
        header = bytes(self._data[:4])
        if header[:2] != CDR_LE_HEADER[:2]:
            raise CdrError(f"not little-endian plain CDR: header {header.hex()}")
        self._pos = len(CDR_LE_HEADER)

    def _align(self, size: int) -> None:
        self._pos += -(self._pos - len(CDR_LE_HEADER)) % size

    def _take(self, n: int) -> memoryview:
        end = self._pos + n
        if end > len(self._data):
            raise CdrError(f"CDR buffer truncated: need {end} bytes, have {len(self._data)}")
        view = self._data[self._pos : end]
        self._pos = end
        return view

    def primitive(self, kind: str) -> object:
        """Read one primitive of ROS type `kind`."""
        code, size = _PRIMITIVES[kind]
        self._align(size)
        return struct.unpack("<" + code, self._take(size))[0]

    def uint32(self) -> int:
        """Read a uint32 (lengths and counts)."""
        self._align(4)
        return int(struct.unpack("<I", self._take(4))[0])

    def primitives(self, kind: str) -> list[object]:
        """Read a sequence of primitives."""
        n = self.uint32()
        if n == 0:
            return []
        code, size = _PRIMITIVES[kind]
        self._align(size)
        return list(struct.unpack(f"<{n}{code}", self._take(n * size)))

    def string(self) -> str:
        """Read a string (the NUL terminator is checked and dropped)."""
        n = self.uint32()
        if n == 0:  # tolerated: some writers encode "" as length 0
            return ""
        raw = bytes(self._take(n))
        if raw[-1] != 0:
            raise CdrError("CDR string is not NUL-terminated")
        return raw[:-1].decode("utf-8")

    def strings(self) -> list[str]:
        """Read a sequence of strings."""
        return [self.string() for _ in range(self.uint32())]

    def count(self) -> int:
        """Read the element count of a sequence of structures."""
        return self.uint32()

    @property
    def remaining(self) -> int:
        """Bytes left after the current position (trailing padding is allowed)."""
        return len(self._data) - self._pos
