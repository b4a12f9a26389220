"""The plain reference of the feature field's stencil sum, kept as the twin the fast path is tested against.

`splat_field_reference` is the straightforward torch implementation `field.splat_field` had before it
became fast (pixie_gs/field_stencil.py): Gaussians grouped by reach in half-voxel steps, every voxel
centre of a ball of radius reach + 0.87 voxel around the base voxel tested, accepted pairs summed with
`index_add_`. Same arguments and result as `field.splat_field`; slower, simpler, and easy to check by eye.
"""
from __future__ import annotations

import math

from .field import eigvals_sym_3x3, inverse_3x3


def splat_field_reference(means, covariances, alphas, features, resolution: int = 64, filter_voxels: float = 0.5,
                          cutoff_sigma: float = 3.0, max_radius_voxels: int = 6, batch_index=None,
                          batch_size: int = 1, chunk_pairs: int | None = None):
    """Density and opacity-weighted feature sums of Gaussians at voxel centres (torch tensors), plainly.

    means (M,3) in the unit cube, covariances (M,3,3) in unit-cube units², alphas (M,), features
    (M,F). `batch_index` (M,) long puts each Gaussian into one of `batch_size` grids (used by
    training to evaluate several objects in one pass). Returns (density (B,N³), feature sums
    (B,N³,F)); divide the sums by the density for weighted means. All on `means.device`.
    """
    import torch

    dev = means.device
    if chunk_pairs is None:  # bigger chunks on a GPU: fewer launches, memory is plentiful
        chunk_pairs = 16_000_000 if dev.type == "cuda" else 2_000_000
    n = int(resolution)
    m = means.shape[0]
    f = features.shape[1]
    pad = int(math.ceil(max_radius_voxels - 0.5 + 0.87))  # the largest stencil offset
    np_ = n + 2 * pad  # padded grid side: stencils never leave it, so no bounds test per pair
    acc = torch.zeros(batch_size * np_ ** 3, f + 1, device=dev, dtype=torch.float32)
    if m:
        h = 1.0 / n
        cov = covariances.to(torch.float32) + (filter_voxels * h) ** 2 * torch.eye(3, device=dev)
        prec = inverse_3x3(cov).float()
        # Reach of the cutoff ellipsoid (voxels) is cutoff·√λmax; group Gaussians by it in half-voxel
        # steps. The mean lies within 0.87 voxel (half-diagonal) of its base voxel's centre, so offsets
        # with |o| ≤ reach + 0.87 cover every voxel centre the ellipsoid can contain.
        reach = cutoff_sigma * torch.sqrt(eigvals_sym_3x3(cov)[:, 2].float()) * n
        reach_key = torch.clamp(torch.ceil(reach * 2.0) / 2.0, 0.5, max_radius_voxels - 0.5)
        base = torch.floor(means * n).long().clamp_(0, n - 1)  # voxel containing the centre
        delta = (base.float() + 0.5) * h - means  # centre of that voxel minus the mean (M,3)
        # maha(g, o) = h² oᵀPo + 2h oᵀPδ + δᵀPδ: one (G,10)@(10,K) matmul per chunk.
        p6 = torch.stack([prec[:, 0, 0], prec[:, 1, 1], prec[:, 2, 2],
                          2 * prec[:, 0, 1], 2 * prec[:, 0, 2], 2 * prec[:, 1, 2]], dim=1) * h * h
        pd = torch.einsum("gij,gj->gi", prec, delta) * (2 * h)
        cst = torch.einsum("gi,gi->g", delta, pd) / (2 * h)
        coef = torch.cat([p6, pd, cst[:, None]], dim=1)  # (M,10)
        bidx = torch.zeros(m, dtype=torch.long, device=dev) if batch_index is None else batch_index.long()
        base_flat = ((bidx * np_ + base[:, 0] + pad) * np_ + base[:, 1] + pad) * np_ + base[:, 2] + pad
        alpha = alphas.to(torch.float32)[:, None]
        weighted = torch.cat([alpha, alpha * features.to(torch.float32)], dim=1)  # α·[1, f]
        cut2 = cutoff_sigma ** 2
        for key in torch.unique(reach_key).tolist():
            sel = torch.nonzero(reach_key == key).squeeze(1)
            r = int(math.ceil(key + 0.87))
            rng = torch.arange(-r, r + 1, device=dev)
            off = torch.stack(torch.meshgrid(rng, rng, rng, indexing="ij"), dim=-1).reshape(-1, 3)
            off = off[(off ** 2).sum(1) <= (key + 0.87) ** 2]
            o = off.float()
            basis = torch.stack([o[:, 0] ** 2, o[:, 1] ** 2, o[:, 2] ** 2, o[:, 0] * o[:, 1], o[:, 0] * o[:, 2],
                                 o[:, 1] * o[:, 2], o[:, 0], o[:, 1], o[:, 2], torch.ones_like(o[:, 0])], dim=0)
            off_flat = (off[:, 0] * np_ + off[:, 1]) * np_ + off[:, 2]
            per_chunk = max(1, chunk_pairs // off.shape[0])
            for start in range(0, sel.numel(), per_chunk):
                g = sel[start:start + per_chunk]
                maha = coef[g] @ basis  # (G,K)
                gi, ki = torch.nonzero(maha <= cut2, as_tuple=True)
                gg = g[gi]
                # maha < 0 only where rounding left Σ not positive definite (a needle ~1e4× longer than
                # wide): weight α there, as at a centre, never α·exp(+…) (stop 53: 1e25 densities, NaN)
                w = torch.exp(-0.5 * maha[gi, ki].clamp_min(0.0))
                acc.index_add_(0, base_flat[gg] + off_flat[ki], w[:, None] * weighted[gg])
    acc = acc.view(batch_size, np_, np_, np_, f + 1)[:, pad:pad + n, pad:pad + n, pad:pad + n]
    acc = acc.reshape(batch_size, n ** 3, f + 1)
    return acc[..., 0].contiguous(), acc[..., 1:].contiguous()
