"""Exact k-nearest neighbours in 3-D with numpy only (a uniform cell grid, no KD-tree).

Why: diagnose's checks need nearest Gaussians (spacing, ICP, neighbouring tracks) once per run;
importing scipy.spatial for that costs ~0.6–0.8 s, more than the queries themselves. The points
are hashed into cells of about one point each; a query looks at the (2r+1)³ cells around its own
(r = 1, then 2) and its k-th distance is certain once it is ≤ r·h (no point outside the block
can be closer); the rest fall back to a brute-force pass. `knn_brute` is the plain reference.
Distances are Euclidean, in the points' units; among equal distances the index may differ from
another method's.
"""
from __future__ import annotations

import numpy as np

_CHUNK_PAIRS = 2_000_000   # candidate pairs per block of queries (memory ~ 40 B each)


def knn_brute(points: np.ndarray, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference: (distances (m,k), indices (m,k)) of the k nearest `points` to each query."""
    points = np.asarray(points, np.float64)
    queries = np.asarray(queries, np.float64)
    k = min(k, len(points))
    d_out = np.empty((len(queries), k))
    i_out = np.empty((len(queries), k), np.int64)
    step = max(1, _CHUNK_PAIRS // max(len(points), 1))
    for a in range(0, len(queries), step):
        q = queries[a:a + step]
        diff = q[:, None, :] - points[None, :, :]
        d2 = np.einsum("ijk,ijk->ij", diff, diff)
        part = np.argpartition(d2, k - 1, axis=1)[:, :k] if k < len(points) else \
            np.broadcast_to(np.arange(len(points)), d2.shape)
        dk = np.take_along_axis(d2, part, axis=1)
        order = np.argsort(dk, axis=1, kind="stable")
        i_out[a:a + step] = np.take_along_axis(part, order, axis=1)
        d_out[a:a + step] = np.sqrt(np.take_along_axis(dk, order, axis=1))
    return d_out, i_out


class CellGrid:
    """Points hashed into a uniform grid of cubic cells of side `h` (≈ one point per cell)."""

    def __init__(self, points: np.ndarray, per_cell: float = 1.0) -> None:
        p = np.asarray(points, np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
            raise ValueError(f"points must be a non-empty (N,3) array, got shape {p.shape}")
        self.points = p
        lo = p.min(axis=0)
        ext = p.max(axis=0) - lo
        span = max(float(ext.max()), 1e-30)
        vol = float(np.prod(np.maximum(ext, 1e-3 * span)))
        h = (vol * per_cell / len(p)) ** (1.0 / 3.0)
        while True:
            dims = np.floor(ext / h).astype(np.int64) + 1
            if int(np.prod(dims)) <= 4 * len(p) + 64:
                break
            h *= 1.25
        self.h, self.lo, self.dims = h, lo, dims
        key = self._key(self._cell(p))
        self.order = np.argsort(key, kind="stable")
        self.sorted_points = p[self.order]   # cell after cell: candidates are gathered near each other
        counts = np.bincount(key, minlength=int(np.prod(dims)))
        self.start = np.concatenate([[0], np.cumsum(counts)])

    def _cell(self, x: np.ndarray) -> np.ndarray:
        return np.floor((x - self.lo) / self.h).astype(np.int64)

    def _key(self, c: np.ndarray) -> np.ndarray:
        return (c[:, 0] * self.dims[1] + c[:, 1]) * self.dims[2] + c[:, 2]

    def _ring_query(self, q: np.ndarray, k: int, r: int) -> tuple[np.ndarray, np.ndarray]:
        """k best (distances, indices) among the points in the (2r+1)³ cells around each query
        (inf / −1 where fewer than k are there)."""
        c = self._cell(q)
        rng = np.arange(-r, r + 1)
        off = np.stack(np.meshgrid(rng, rng, rng, indexing="ij"), axis=-1).reshape(-1, 3)
        cells = c[:, None, :] + off[None, :, :]                              # (m, B, 3)
        inside = np.all((cells >= 0) & (cells < self.dims), axis=2)
        keys = np.where(inside, self._key(np.where(inside[..., None], cells, 0).reshape(-1, 3)).reshape(inside.shape), 0)
        s = np.where(inside, self.start[keys], 0)
        n = np.where(inside, self.start[keys + 1] - s, 0)
        total = n.sum(axis=1)
        m = len(q)
        width = max(int(total.max(initial=0)), k)
        if m > 1 and m * width > 2 * _CHUNK_PAIRS:  # crowded cells: fewer queries at a time
            h = m // 2
            (d1, i1), (d2_, i2) = self._ring_query(q[:h], k, r), self._ring_query(q[h:], k, r)
            return np.concatenate([d1, d2_]), np.concatenate([i1, i2])
        # flat list of (query, candidate) pairs, laid out query after query
        flat_n = n.ravel()
        pair_q = np.repeat(np.arange(m), total)
        first = np.repeat(s.ravel(), flat_n)
        cell_begin = np.repeat(np.cumsum(flat_n) - flat_n, flat_n)
        pos = first + (np.arange(int(flat_n.sum())) - cell_begin)       # into sorted_points
        at = pair_q * width + (np.arange(len(pair_q)) - np.repeat(np.cumsum(total) - total, total))
        d2 = np.full(m * width, np.inf)
        where = np.full(m * width, -1, np.int64)
        diff = self.sorted_points[pos] - np.repeat(q, total, axis=0)
        d2[at] = np.einsum("ij,ij->i", diff, diff)
        where[at] = pos
        d2, where = d2.reshape(m, width), where.reshape(m, width)
        part = np.argpartition(d2, k - 1, axis=1)[:, :k] if k < width else np.tile(np.arange(width), (m, 1))
        dk = np.take_along_axis(d2, part, axis=1)
        order = np.argsort(dk, axis=1, kind="stable")
        best = np.take_along_axis(np.take_along_axis(where, part, 1), order, 1)
        return np.sqrt(np.take_along_axis(dk, order, axis=1)), np.where(best >= 0, self.order[np.maximum(best, 0)], -1)

    def query(self, queries: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(distances (m,k), indices (m,k)) of the k nearest points to each query, nearest first
        (k is capped at the number of points)."""
        q = np.asarray(queries, np.float64).reshape(-1, 3)
        k = min(int(k), len(self.points))
        if k < 1:
            raise ValueError("k must be ≥ 1")
        dist = np.full((len(q), k), np.inf)
        ids = np.full((len(q), k), -1, np.int64)
        finite = np.isfinite(q).all(axis=1)                  # others: inf / −1
        with np.errstate(invalid="ignore", over="ignore"):
            cell = np.floor((q - self.lo) / self.h)
        near = finite & np.all((cell >= -1) & (cell <= self.dims), axis=1)
        far = np.nonzero(finite & ~near)[0]                  # more than a cell off the grid: brute force
        todo = np.nonzero(near)[0]
        for r in (1, 2):
            if len(todo) == 0:
                break
            block = max(1, _CHUNK_PAIRS // ((2 * r + 1) ** 3 * 4))
            left = []
            for a in range(0, len(todo), block):
                sel = todo[a:a + block]
                d, i = self._ring_query(q[sel], k, r)
                sure = d[:, -1] <= r * self.h
                dist[sel[sure]], ids[sel[sure]] = d[sure], i[sure]
                left.append(sel[~sure])
            todo = np.concatenate(left) if left else todo[:0]
        todo = np.concatenate([todo, far])
        if len(todo):
            dist[todo], ids[todo] = knn_brute(self.points, q[todo], k)
        return dist, ids


def knn(points: np.ndarray, queries: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(distances (m,k), indices (m,k)) of the k nearest `points` to each of `queries`."""
    return CellGrid(points).query(queries, k)
