"""INRIA 3DGS `.ply` (the original Gaussian-splatting layout, also written by gsplat and nerfstudio).

One `vertex` element: `x y z`, optional `nx ny nz`, `f_dc_0..2`, `f_rest_*` (0, 9, 24 or 45),
`opacity` (logit), `scale_0..2` (log std-dev), `rot_0..3` (quaternion w,x,y,z), in any order and
any scalar type (float64 exports are read). Every other property travels byte for byte in
`extras`. Reading is strict: the data must be exactly as long as the header's counts say.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from ..atomic import atomic_path
from ..errors import InputError
from ..splat import _CORE_GROUPS, _VALID_REST_COUNTS, SplatCloud, _is_extra, _rest_index
from .ply_header import PlyHeader, check_binary_size, read_header

# properties whose presence marks a PLY vertex table as Gaussians rather than plain points
GAUSSIAN_MARKERS = ("opacity", "scale_0", "rot_0", "f_dc_0")
VALID_REST_COUNTS = _VALID_REST_COUNTS
CORE_GROUPS = _CORE_GROUPS
is_extra = _is_extra
rest_index = _rest_index


def check_strict(header: PlyHeader, path: Path) -> None:
    """Refuse list properties on the vertex element and data whose size disagrees with the header."""
    vertex = header.element("vertex")
    if vertex is None:
        raise InputError("has no 'vertex' element", path)
    lists = [p.name for p in vertex.properties if p.is_list]
    if lists:
        raise InputError(f"vertex element has list property '{lists[0]}'; a 3DGS vertex holds scalars only",
                         path)
    variable = any(el.has_list and el.count > 0 for el in header.elements)  # rows of unknown size
    if header.format != "ascii":
        if not variable:
            check_binary_size(header, path.stat().st_size, path)
        return
    with open(path, "rb") as fh:
        fh.seek(header.data_offset)
        lines = sum(1 for line in fh if line.strip())
    expected = sum(el.count for el in header.elements)
    if lines < expected:
        raise InputError(f"truncated PLY data: header declares {expected} rows, the file has {lines} lines",
                         path)
    if lines > expected and not variable:
        raise InputError(f"PLY data longer than its header says: header declares {expected} rows but the "
                         f"file has {lines} lines (wrong vertex count?)", path)


def _vertex_table(header: PlyHeader, path: Path) -> np.ndarray | None:
    """The vertex rows read straight into memory (one sequential read), for binary files whose
    elements before `vertex` have fixed-size rows; None otherwise (plyfile reads those)."""
    if header.format == "ascii":
        return None
    offset = header.data_offset
    for el in header.elements:
        if el.name == "vertex":
            return np.fromfile(path, dtype=el.dtype(header.byte_order), count=el.count, offset=offset)
        if el.has_list and el.count > 0:
            return None
        offset += el.count * el.dtype(header.byte_order).itemsize
    return None


def read(path: str | Path) -> SplatCloud:
    """Read an INRIA 3DGS `.ply` (binary either endian, or ascii) into a validated SplatCloud."""
    path = Path(path)
    header = read_header(path)
    check_strict(header, path)
    data = _vertex_table(header, path)
    if data is None:
        data = _read_with_plyfile(path)
    cloud = _to_cloud(data, path)
    cloud.comments = list(header.comments)
    return cloud


def _read_with_plyfile(path: Path) -> np.ndarray:
    try:
        ply = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for malformed or short files
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "early end" in text.lower() or "truncat" in text.lower() or "expected" in text.lower():
            raise InputError(f"truncated or malformed PLY data ({text})", path) from None
        raise InputError(f"cannot parse PLY ({text})", path) from None
    return ply["vertex"].data


def _to_cloud(data: np.ndarray, path: Path) -> SplatCloud:
    """SplatCloud from a structured vertex table (any property order, scalar types and byte order)."""
    names = list(data.dtype.names or ())
    missing = [p for group in CORE_GROUPS.values() for p in group if p not in names]
    if missing:
        raise InputError(f"missing required vertex properties: {', '.join(missing)}", path)
    rest_names = [p for p in names if p.startswith("f_rest_")]
    expected_rest = [f"f_rest_{i}" for i in range(len(rest_names))]
    if len(rest_names) not in VALID_REST_COUNTS or sorted(rest_names, key=rest_index) != expected_rest:
        raise InputError(
            f"has {len(rest_names)} f_rest properties; a 3DGS file has 0, 9, 24 or 45 (f_rest_0…f_rest_N-1)",
            path,
        )

    kinds = {data.dtype[p] for p in names}
    kind = next(iter(kinds))
    matrix = None
    if len(kinds) == 1 and kind.kind == "f" and data.dtype.itemsize == len(names) * kind.itemsize:
        matrix = data.view(kind).reshape(len(data), len(names))  # all one float type: a 2-D view
    index = {p: i for i, p in enumerate(names)}

    def columns(props: tuple[str, ...] | list[str]) -> np.ndarray:
        if matrix is not None:
            return np.ascontiguousarray(matrix[:, [index[p] for p in props]], dtype=np.float32)
        out = np.empty((len(data), len(props)), dtype=np.float32)
        for j, p in enumerate(props):
            out[:, j] = data[p]
        return out

    cloud = SplatCloud(
        means=columns(CORE_GROUPS["means"]),
        log_scales=columns(CORE_GROUPS["log_scales"]),
        rotations=columns(CORE_GROUPS["rotations"]),
        opacity_logits=columns(CORE_GROUPS["opacity_logits"])[:, 0].copy(),
        sh_dc=columns(CORE_GROUPS["sh_dc"]),
        sh_rest=columns(expected_rest),
        extras={p: np.ascontiguousarray(data[p]).astype(data.dtype[p].newbyteorder("=")) for p in names
                if is_extra(p)},
        property_order=names,
        source=str(path),
    )
    cloud.source_format = "inria_ply"
    cloud.validate()
    return cloud


def _column(cloud: SplatCloud, name: str) -> np.ndarray:
    for attr, group in CORE_GROUPS.items():
        if name in group:
            arr = getattr(cloud, attr)
            return arr if arr.ndim == 1 else arr[:, group.index(name)]
    if name.startswith("f_rest_"):
        return cloud.sh_rest[:, rest_index(name)]
    return cloud.extras[name]


def to_structured(cloud: SplatCloud) -> np.ndarray:
    """The vertex table as a little-endian structured array in the cloud's property order."""
    order = list(cloud.property_order) or cloud._default_order()
    present = set(order)
    order += [f"f_rest_{i}" for i in range(cloud.sh_rest.shape[1]) if f"f_rest_{i}" not in present]
    order += [k for k in cloud.extras if k not in present]
    order = [n for n in order if not n.startswith("f_rest_") or rest_index(n) < cloud.sh_rest.shape[1]]
    order = [n for n in order if not is_extra(n) or n in cloud.extras]
    order += [n for g in CORE_GROUPS.values() for n in g if n not in order]
    dtypes = []
    for name in order:
        dt = cloud.extras[name].dtype if name in cloud.extras else np.dtype(np.float32)
        dtypes.append((name, dt.newbyteorder("<")))
    table = np.empty(len(cloud), dtype=dtypes)
    for name in order:
        table[name] = _column(cloud, name)
    return table


def write(cloud: SplatCloud, path: str | Path) -> None:
    """Write `cloud` as binary little-endian 3DGS `.ply`, atomically (temp file + rename)."""
    cloud.validate()
    element = PlyElement.describe(to_structured(cloud), "vertex")
    with atomic_path(path, suffix=".ply.tmp") as tmp:
        PlyData([element], text=False, byte_order="<", comments=list(cloud.comments)).write(str(tmp))
