"""Every on-disk splat format pixie-gs reads and writes, recognised by content, not by extension.

Formats (one module each): `inria_ply` (original 3DGS / gsplat / nerfstudio PLY), `compressed_ply`
(SuperSplat / PlayCanvas), `splat` (antimatter15), `spz` (Niantic). `detect_format` looks at the
bytes (PLY header elements and properties, gzip / NGSP magic, record size); a file in a format we
do not read gets a one-line InputError naming what was found.
"""
from __future__ import annotations

import gzip
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError, require_file
from ..splat import SplatCloud

FORMATS = ("inria_ply", "compressed_ply", "splat", "spz")
LABELS = {
    "inria_ply": "INRIA 3DGS PLY",
    "compressed_ply": "SuperSplat compressed PLY",
    "splat": "antimatter15 .splat",
    "spz": "Niantic .spz",
}
ALIASES = {"ply": "inria_ply", "inria": "inria_ply", "compressed": "compressed_ply",
           "compressed.ply": "compressed_ply", "supersplat": "compressed_ply", ".splat": "splat", ".spz": "spz"}
SPZ_MAGIC = b"NGSP"  # 0x5053474e little endian


def _describe_start(head: bytes) -> str:
    shown = head[:8]
    if all(32 <= b < 127 for b in shown):
        return repr(shown.decode("ascii"))
    return shown.hex(" ")


def _ply_kind(path: Path) -> str:
    from .compressed_ply import is_compressed
    from .inria_ply import GAUSSIAN_MARKERS
    from .ply_header import read_header

    header = read_header(path)
    if is_compressed(header):
        return "compressed_ply"
    vertex = header.element("vertex")
    if vertex is None:
        if header.element("chunk") is not None:
            raise InputError("has a 'chunk' element but no packed 'vertex' element: not a complete compressed PLY",
                             path)
        raise InputError("has no 'vertex' element", path)
    if any(m in vertex.names for m in GAUSSIAN_MARKERS):
        return "inria_ply"
    if header.element("face") is not None and header.element("face").count > 0:
        raise InputError(f"is a PLY mesh ({header.element('face').count} faces), not a splat: "
                         "use `pixie convert MESH OUT.ply`", path)
    shown = " ".join(vertex.names[:8]) + (" …" if len(vertex.names) > 8 else "")
    raise InputError(f"is a PLY point cloud without Gaussian properties (vertex has {shown}); a splat needs "
                     "opacity, scale_0..2, rot_0..3 and f_dc_0..2", path)


def _plausible_splat(path: Path, size: int) -> bool:
    """True when the first records of a headerless file look like antimatter15 `.splat` records."""
    from .splat_antimatter import RECORD

    if size == 0 or size % RECORD.itemsize:
        return False
    n = min(size // RECORD.itemsize, 4096)
    rec = np.fromfile(path, dtype=RECORD, count=n)
    pos, scale = rec["position"].astype(np.float64), rec["scale"].astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = (np.isfinite(pos).all(axis=1) & (np.abs(pos) < 1e7).all(axis=1)
              & np.isfinite(scale).all(axis=1) & (scale > 0).all(axis=1) & (scale < 1e6).all(axis=1)
              & (np.abs(rec["rot"].astype(np.int64) - 128).sum(axis=1) > 0))
    return bool(ok.mean() >= 0.99)


def _first_bytes(path: Path, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def detect_format(path: str | Path) -> str:
    """The format of the splat file at `path` by its content: one of FORMATS.

    InputError (one line, naming what was found) for anything else.
    """
    path = require_file(path, "a splat file")
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head:
        raise InputError("is empty (0 bytes)", path)
    if head.startswith(b"ply"):
        return _ply_kind(path)
    if head.startswith(SPZ_MAGIC):
        return "spz"
    if head.startswith(b"\x1f\x8b"):
        try:
            with gzip.open(path, "rb") as gz:
                inner = gz.read(16)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(f"is a damaged gzip file ({exc})", path) from None
        if inner.startswith(SPZ_MAGIC):
            return "spz"
        raise InputError(f"is gzip but not .spz (inner bytes start {_describe_start(inner)}, no NGSP magic)",
                         path)
    if head.startswith(b"glTF"):
        raise InputError("is a glTF binary (mesh), not a splat: use `pixie convert MESH OUT.ply`", path)
    if head.lstrip().startswith(b"{") and b'"asset"' in _first_bytes(path, 4096):
        raise InputError("is a glTF JSON file (mesh), not a splat: use `pixie convert MESH OUT.ply`", path)
    if head.startswith(b"PK\x03\x04"):
        raise InputError("is a zip archive (e.g. PlayCanvas .sog), which pixie-gs does not read; convert it "
                         "to .ply with SuperSplat or splat-transform", path)
    if head.startswith(b"solid") or (len(head) >= 6 and head[:2] in (b"v ", b"# ") and b"\nv " in head):
        raise InputError("looks like a mesh (STL/OBJ), not a splat: use `pixie convert MESH OUT.ply`", path)
    if _plausible_splat(path, size):
        return "splat"
    if path.suffix.lower() == ".splat" and size % 32:
        raise InputError(f"is not an antimatter15 .splat file: size {size} bytes is not a multiple of 32", path)
    raise InputError(f"unknown format (first bytes {_describe_start(head)}): not a PLY, compressed PLY, "
                     ".splat or .spz splat", path)


def _module(fmt: str):
    fmt = ALIASES.get(fmt, fmt)
    if fmt == "inria_ply":
        from . import inria_ply as mod
    elif fmt == "compressed_ply":
        from . import compressed_ply as mod
    elif fmt == "splat":
        from . import splat_antimatter as mod
    elif fmt == "spz":
        from . import spz as mod
    else:
        raise InputError(f"unknown splat format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return mod


def read_any(path: str | Path) -> SplatCloud:
    """Read a splat in any supported format (detected by content) into a validated SplatCloud."""
    fmt = detect_format(path)
    cloud = _module(fmt).read(path)
    cloud.source_format = fmt
    return cloud


def format_for_path(path: str | Path) -> str:
    """Output format implied by a file name: .splat, .spz, .compressed.ply, otherwise INRIA .ply."""
    name = Path(path).name.lower()
    if name.endswith(".compressed.ply"):
        return "compressed_ply"
    if name.endswith(".splat"):
        return "splat"
    if name.endswith(".spz"):
        return "spz"
    return "inria_ply"


def normalise_format(fmt: str) -> str:
    """A format name from FORMATS for a user's spelling (e.g. 'ply', 'compressed', '.spz')."""
    name = ALIASES.get(fmt.lower(), fmt.lower())
    if name not in FORMATS:
        raise InputError(f"unknown splat format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return name


def write_any(cloud: SplatCloud, path: str | Path, fmt: str | None = None) -> str:
    """Write `cloud` to `path` in `fmt` (default: from the file name); returns the format used."""
    fmt = normalise_format(fmt) if fmt else format_for_path(path)
    _module(fmt).write(cloud, path)
    return fmt


def lossy_note(cloud: SplatCloud, fmt: str) -> str | None:
    """One line saying what writing `cloud` as `fmt` loses, or None when nothing is lost."""
    fmt = normalise_format(fmt)
    extras = [k for k in cloud.extras]
    rest = cloud.sh_rest.shape[1]
    if fmt == "inria_ply":
        return None
    dropped = []
    if fmt == "splat" and rest:
        dropped.append(f"{rest} f_rest")
    if extras:
        dropped.append(f"{len(extras)} extra propert{'y' if len(extras) == 1 else 'ies'} "
                       f"({', '.join(extras[:6])}{' …' if len(extras) > 6 else ''})")
    what = {
        "splat": ".splat keeps SH degree 0 only and 8-bit colour, opacity and rotation",
        "compressed_ply": "compressed PLY quantises to 11/10/11-bit positions and scales per 256-Gaussian chunk, "
                          "8-bit colour/opacity/SH and reorders Gaussians along a Morton curve",
        "spz": ".spz quantises to 24-bit fixed-point positions, 8-bit scales/colour/opacity/SH",
    }[fmt]
    return what + ("; " + " and ".join(dropped) + " dropped" if dropped else "")
