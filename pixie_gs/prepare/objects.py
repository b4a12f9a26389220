"""Objects: dense clusters of the non-floater, non-ground Gaussians, found as connected components
of occupied cells (26-neighbourhood, sparse: no dense 3D array, so room-sized captures cost the
same as objects), or the user's crop (box, sphere or a point on the object)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .density import NEIGHBOUR_OFFSETS, cell_keys, dense_grid, pack


ROBUST_SAMPLE = 200_000  # robust boxes of larger sets are read from a sample this big


@dataclass
class Crop:
    """User-given object region in file coordinates: kind "box" (lo, hi), "sphere" (centre,
    radius) or "point" (a point on the object: its cluster is the object)."""

    kind: str
    values: tuple[float, ...]

    def contains(self, x: np.ndarray) -> np.ndarray:
        v = np.asarray(self.values, np.float64)
        if self.kind == "box":
            return np.all((x >= v[:3]) & (x <= v[3:]), axis=1)
        if self.kind == "sphere":
            return np.linalg.norm(x - v[:3], axis=1) <= v[3]
        raise ValueError("a point crop selects a cluster, not a region")


def parse_crop(text: str | None) -> Crop | None:
    """`box:x0,y0,z0,x1,y1,z1`, `sphere:cx,cy,cz,r` or `point:x,y,z` (file coordinates) → Crop."""
    if text is None or text == "":
        return None
    kind, _, rest = text.partition(":")
    need = {"box": 6, "sphere": 4, "point": 3}
    try:
        values = tuple(float(v) for v in rest.split(",") if v.strip())
    except ValueError:
        values = ()
    kind = kind.strip().lower()
    if kind not in need or len(values) != need[kind] or not np.isfinite(values).all():
        raise InputError(f"--crop '{text}' must be box:x0,y0,z0,x1,y1,z1, sphere:cx,cy,cz,r or point:x,y,z")
    if kind == "box" and any(values[i] > values[i + 3] for i in range(3)):
        raise InputError(f"--crop '{text}': the box's first corner must be ≤ its second on every axis")
    if kind == "sphere" and values[3] <= 0:
        raise InputError(f"--crop '{text}': the radius must be > 0")
    return Crop(kind, values)


def components(points: np.ndarray, cell: float) -> np.ndarray:
    """Connected-component label (N,) of each point: points whose cells touch (26-neighbourhood)
    share a label. Labels are 0..K-1."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(points) == 0:
        return np.zeros(0, np.int64)
    dense = dense_grid(points, cell)
    if dense is not None:  # small grid: label it densely (no sort, no graph)
        from scipy.ndimage import label as label_grid

        lin, shape = dense
        occupied = np.zeros(int(np.prod(shape)), bool)
        occupied[lin] = True
        grid, _ = label_grid(occupied.reshape(shape), structure=np.ones((3, 3, 3), bool))
        return grid.reshape(-1)[lin].astype(np.int64) - 1
    idx, keys = cell_keys(points, cell)
    uniq, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    cells = idx[first]
    rows, cols = [], []
    for off in NEIGHBOUR_OFFSETS[:13]:  # half the neighbourhood: the graph is undirected
        nk = pack(cells + off)
        pos = np.minimum(np.searchsorted(uniq, nk), len(uniq) - 1)
        hit = uniq[pos] == nk
        rows.append(np.nonzero(hit)[0])
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(uniq), len(uniq)))
    _, label = connected_components(graph, directed=False)
    return label[inverse.reshape(-1)]


def robust_box(x: np.ndarray, mask: np.ndarray | None = None, q: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) per axis at the q-th and (100−q)-th percentiles of x (or of x[mask]): the extent
    without stragglers. Large sets are read from a fixed random sample (ROBUST_SAMPLE)."""
    sel = np.nonzero(mask)[0] if mask is not None else None
    count = len(x) if sel is None else len(sel)
    if count > ROBUST_SAMPLE:  # percentiles of a fixed random sample: ±0.1 % of the count, much faster
        pick = np.random.default_rng(0).integers(0, count, ROBUST_SAMPLE)
        sel = pick if sel is None else sel[pick]
    sub = x if sel is None else x[sel]
    lo, hi = np.percentile(sub, [q, 100.0 - q], axis=0)
    return lo, hi


def fit_box(x: np.ndarray, grow: float = 0.1, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Box used to normalise an object into the unit cube: the min/max of its Gaussians (x, or
    x[mask]), clipped to its robust box grown by `grow` of its size per side (a clean object
    keeps its min/max)."""
    lo, hi = robust_box(x, mask)
    pad = grow * (hi - lo).max()
    sub = x if mask is None else x[mask]
    return np.maximum(sub.min(axis=0), lo - pad), np.minimum(sub.max(axis=0), hi + pad)


SHEET_RATIO = 0.15  # a box whose thinnest side is under this share of its longest is a sheet (wall, floor, backdrop)
BACKGROUND_SIZE = 3.0  # a cluster this many times the main object's size is background if it is a sheet or surrounds it


def looks_like_background(lo: np.ndarray, hi: np.ndarray, main_lo: np.ndarray, main_hi: np.ndarray) -> bool:
    """Whether a cluster with box (lo, hi), in the up frame, much larger than the main object (box main_lo,
    main_hi), is background rather than a second object: a sheet (a wall, a floor, a backdrop), or a
    shell whose horizontal footprint holds the main object's centre (a room, a table under it). A big
    compact thing standing beside the main object (a crate beside a ball, a sand pile beside a cushion)
    is an object."""
    if float((hi - lo).max()) <= BACKGROUND_SIZE * float((main_hi - main_lo).max()):
        return False
    extent = np.sort(hi - lo)
    if extent[0] < SHEET_RATIO * extent[2]:
        return True
    centre = 0.5 * (main_lo + main_hi)
    return bool(np.all((centre[:2] >= lo[:2]) & (centre[:2] <= hi[:2])))


def pick_objects(points_up: np.ndarray, weights: np.ndarray, labels: np.ndarray, centre: np.ndarray,
                 merge_grow: float = 0.2, companion_share: float = 0.3) -> np.ndarray:
    """Object id (N,) per point (−1: not an object) from component `labels`, in the up frame.

    The main object is the heaviest component weighted by closeness to the scene `centre`
    (captures are framed on their subject); components whose centre lies within its box grown
    by `merge_grow` of its size join it (leaves of a tree); other components at least
    `companion_share` as heavy become further objects unless they look like background
    (`looks_like_background`: much larger than the main object and a sheet or around it)."""
    n_lab = int(labels.max()) + 1 if len(labels) else 0
    mass = np.bincount(labels, weights=weights, minlength=n_lab)
    cen = np.stack([np.bincount(labels, weights=weights * points_up[:, k], minlength=n_lab) for k in range(3)], 1)
    cen /= np.maximum(mass, 1e-12)[:, None]
    probe = points_up[:: max(1, len(points_up) // ROBUST_SAMPLE), :2]  # an even sample is enough for a radius
    scene_r = float(np.percentile(np.linalg.norm(probe - centre[:2], axis=1), 90)) or 1.0
    d = np.linalg.norm(cen[:, :2] - centre[:2], axis=1) / scene_r
    order = np.argsort(-(mass / (1.0 + 4.0 * d ** 2)))
    out = np.full(len(points_up), -1, np.int32)
    taken = np.zeros(n_lab, bool)
    objects: list[np.ndarray] = []
    for lab in order:
        if taken[lab]:
            continue
        if objects and mass[lab] < companion_share * mass[order[0]]:
            break
        group = [lab]
        taken[lab] = True
        members = labels == lab
        lo, hi = robust_box(points_up, members)
        if objects and looks_like_background(lo, hi, *main_box):
            continue
        for _ in range(2):  # absorb nearby fragments, twice so chains of leaves join
            pad = merge_grow * (hi - lo).max()
            near = (~taken) & np.all((cen >= lo - pad) & (cen <= hi + pad), axis=1)
            if not near.any():
                break
            group += list(np.nonzero(near)[0])
            taken |= near
            in_group = np.zeros(n_lab, bool)
            in_group[group] = True
            members = in_group[labels]
            lo, hi = robust_box(points_up, members)
        if not objects:
            main_box = (lo, hi)
        out[members] = len(objects)
        objects.append(np.array(group))
    return out
