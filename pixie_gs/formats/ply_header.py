"""PLY header parsing shared by the PLY-based splat formats (INRIA 3DGS and compressed PLY).

Reads only the text header (never the data), so format detection and size checks are cheap on
multi-gigabyte files. The sizes it computes let readers refuse files whose data is longer or
shorter than the header says (a truncated download, a wrong vertex count written by a tool).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

# PLY scalar type names (both spellings) -> numpy type code without byte order
PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
MAX_HEADER_BYTES = 1 << 20  # a header longer than 1 MiB is not a splat header


@dataclass
class PlyProperty:
    name: str
    type: str  # numpy code, e.g. "f4"; for a list property the item type
    list_count_type: str | None = None  # numpy code of the length prefix for list properties

    @property
    def is_list(self) -> bool:
        return self.list_count_type is not None


@dataclass
class PlyElementHeader:
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.properties]

    @property
    def has_list(self) -> bool:
        return any(p.is_list for p in self.properties)

    def dtype(self, byte_order: str) -> np.dtype:
        """Structured dtype of one row (scalar properties only), `byte_order` '<' or '>'."""
        return np.dtype([(p.name, byte_order + p.type) for p in self.properties])


@dataclass
class PlyHeader:
    format: str  # "binary_little_endian" | "binary_big_endian" | "ascii"
    elements: list[PlyElementHeader]
    comments: list[str]
    data_offset: int  # bytes from the start of the file to the first data byte

    @property
    def byte_order(self) -> str:
        return ">" if self.format == "binary_big_endian" else "<"

    def element(self, name: str) -> PlyElementHeader | None:
        for el in self.elements:
            if el.name == name:
                return el
        return None


def read_header(path: str | Path) -> PlyHeader:
    """Parse the header of the PLY file at `path`; InputError (one line) when it is not one."""
    with open(path, "rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
    return parse_header(head, path)


def parse_header(head: bytes, path: str | Path | None = None) -> PlyHeader:
    """Parse a PLY header from the first bytes of a file (`head` must contain 'end_header')."""
    if not head.startswith(b"ply"):
        raise InputError("not a PLY file (missing 'ply' magic)", path)
    end = head.find(b"end_header")
    if end < 0:
        raise InputError("malformed PLY header (no 'end_header' line)", path)
    nl = head.find(b"\n", end)
    if nl < 0:
        raise InputError("malformed PLY header (nothing after 'end_header')", path)
    text = head[:end].decode("ascii", errors="replace").replace("\r", "")
    fmt = None
    elements: list[PlyElementHeader] = []
    comments: list[str] = []
    for lineno, line in enumerate(text.split("\n")[1:], start=2):
        words = line.split()
        if not words or words[0] in ("obj_info",):
            continue
        key = words[0]
        if key == "comment":
            comments.append(line[len("comment"):].strip())
        elif key == "format":
            if len(words) < 2 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise InputError(f"malformed PLY header (line {lineno}: unknown format {line.strip()!r})", path)
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise InputError(f"malformed PLY header (line {lineno}: {line.strip()!r})", path)
            if any(el.name == words[1] for el in elements):  # a reader would see only one of the two
                raise InputError(f"malformed PLY header (line {lineno}: element {words[1][:40]!r} appears twice)",
                                 path)
            elements.append(PlyElementHeader(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise InputError(f"malformed PLY header (line {lineno}: property before any element)", path)
            if len(words) >= 3 and words[-1] in elements[-1].names:
                raise InputError(f"malformed PLY header (line {lineno}: property {words[-1][:40]!r} appears twice "
                                 f"in element {elements[-1].name[:40]!r})", path)
            if len(words) == 5 and words[1] == "list":
                if words[2] not in PLY_TYPES or words[3] not in PLY_TYPES:
                    raise InputError(f"malformed PLY header (line {lineno}: unknown type in {line.strip()!r})",
                                     path)
                elements[-1].properties.append(PlyProperty(words[4], PLY_TYPES[words[3]], PLY_TYPES[words[2]]))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1].properties.append(PlyProperty(words[2], PLY_TYPES[words[1]]))
            else:
                raise InputError(f"malformed PLY header (line {lineno}: {line.strip()!r})", path)
        else:
            raise InputError(f"malformed PLY header (line {lineno}: unknown keyword {key!r})", path)
    if fmt is None:
        raise InputError("malformed PLY header (no 'format' line)", path)
    return PlyHeader(fmt, elements, comments, nl + 1)


def check_binary_size(header: PlyHeader, file_size: int, path: str | Path) -> None:
    """InputError when the data after a binary header is shorter or longer than its counts say.

    Only for headers without list properties (their row size is fixed).
    """
    expected = sum(el.count * el.dtype(header.byte_order).itemsize for el in header.elements)
    actual = file_size - header.data_offset
    if actual == expected:
        return
    summary = ", ".join(f"{el.count} {el.name}" for el in header.elements)
    if actual < expected:
        raise InputError(f"truncated PLY data: header declares {summary} ({expected} bytes of data) but the "
                         f"file holds {actual} bytes", path)
    raise InputError(f"PLY data longer than its header says: header declares {summary} ({expected} bytes) "
                     f"but the file holds {actual} bytes after the header (wrong vertex count?)", path)
