"""Rasteriser-free feature field: a splat evaluated at the voxel centres of an N³ grid.

The cloud is normalised into the unit cube (`SplatCloud.normalized`), then every Gaussian adds its
weight w_i(x) = α_i · G_i(x) to the voxels inside a bounded stencil around it, with the
*unnormalised* Gaussian G_i(x) = exp(-½ dᵀ Σ'_i⁻¹ d), d = x − μ_i. Unnormalised means a Gaussian's
peak contributes its opacity, whatever its size, so the density σ(x) = Σ_i w_i(x) reads like
"how much opaque stuff is here" and occupancy is σ > 0.01 (DESIGN.md).

Σ'_i = Σ_i + s²·I is the Gaussian widened by a small isotropic pre-filter of s = `filter_voxels`
voxel sizes (default 0.5 voxel). Without it a Gaussian much smaller than a voxel falls between
voxel centres and the occupancy gets holes; with it every voxel that contains a Gaussian centre
sees at least α·exp(-½·(0.87/0.5)²) ≈ 0.22·α. `filter_voxels=0` gives the plain formula.

Per-voxel features are opacity-weighted means Σ w_i f_i / Σ w_i of per-Gaussian features
(RGB, opacity, size, anisotropy, SH view-dependence energy, and extra float channels the file
carries such as distilled CLIP features, never label attributes). The stencil of a Gaussian is the
ball of voxels that can hold its `cutoff_sigma`-σ ellipsoid (radius cutoff·√λmax, capped at
`max_radius_voxels`), and only voxels inside the ellipsoid are accumulated, so the cost grows with
the number of Gaussians, not with N³ × Gaussians. The same torch code runs on CPU and CUDA; 3×3
inverses and eigenvalues are closed-form so millions of Gaussians need no solver workspace.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .splat import LABEL_ATTRIBUTES, SplatCloud, UnitCubeTransform

OCCUPANCY_THRESHOLD = 0.01
NORMAL_ATTRIBUTES = ("nx", "ny", "nz")
# Per-Gaussian feature channels every splat has (the "base" set), in grid channel order.
BASE_FEATURES = ("r", "g", "b", "opacity", "log_size", "anisotropy", "sh_energy")
# Grid channels computed from the density itself, placed before the weighted features.
DENSITY_CHANNELS = ("density", "occupancy")
# Input channel subsets used by the model and by the ablation (names refer to grid channels).
INPUT_MODES = {
    "full": None,  # every channel of the grid
    "rgb": DENSITY_CHANNELS + ("r", "g", "b"),
    "occupancy": DENSITY_CHANNELS,
}


def extra_feature_names(cloud: SplatCloud) -> list[str]:
    """Extra per-Gaussian float properties usable as features (e.g. `clip_0..`), in file order.

    Never label attributes (material_id, E, nu, density, part_id) nor normals: those would leak
    the answer or carry no information.
    """
    skip = set(LABEL_ATTRIBUTES) | set(NORMAL_ATTRIBUTES)
    return [name for name, arr in cloud.extras.items()
            if name not in skip and np.issubdtype(arr.dtype, np.floating)]


@dataclass
class FeatureGrid:
    """Voxel-centre values of a splat on an N³ grid over the unit cube.

    `values` is (C, N, N, N) float32 with channels `channels` (density, occupancy, then weighted
    features); `occupancy` is (N, N, N) bool; `transform` maps world → unit cube.
    """

    values: np.ndarray
    occupancy: np.ndarray
    channels: list[str]
    transform: object = None
    resolution: int = 64
    extra: dict = field(default_factory=dict)

    def channel(self, name: str) -> np.ndarray:
        return self.values[self.channels.index(name)]

    def voxel_centres(self) -> np.ndarray:
        """(N³, 3) unit-cube coordinates of the voxel centres, in C order (i, j, k) = (x, y, z)."""
        return voxel_centres(self.resolution)


def voxel_centres(n: int) -> np.ndarray:
    """(n³, 3) unit-cube coordinates of the voxel centres, index order (x, y, z) C-contiguous."""
    c = (np.arange(n, dtype=np.float32) + 0.5) / n
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)


def inverse_3x3(m):
    """Inverse of a batch (M,3,3) of symmetric positive-definite matrices by the adjugate formula.

    Closed form in float64: no solver workspace, so it scales to millions of Gaussians on a GPU
    (batched cuSOLVER/cuBLAS calls need workspace that grows with the batch).
    """
    import torch

    a = m.double()
    c00 = a[:, 1, 1] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 1]
    c01 = a[:, 1, 2] * a[:, 2, 0] - a[:, 1, 0] * a[:, 2, 2]
    c02 = a[:, 1, 0] * a[:, 2, 1] - a[:, 1, 1] * a[:, 2, 0]
    det = a[:, 0, 0] * c00 + a[:, 0, 1] * c01 + a[:, 0, 2] * c02
    adj = torch.stack([
        torch.stack([c00, a[:, 0, 2] * a[:, 2, 1] - a[:, 0, 1] * a[:, 2, 2], a[:, 0, 1] * a[:, 1, 2] - a[:, 0, 2] * a[:, 1, 1]], 1),
        torch.stack([c01, a[:, 0, 0] * a[:, 2, 2] - a[:, 0, 2] * a[:, 2, 0], a[:, 0, 2] * a[:, 1, 0] - a[:, 0, 0] * a[:, 1, 2]], 1),
        torch.stack([c02, a[:, 0, 1] * a[:, 2, 0] - a[:, 0, 0] * a[:, 2, 1], a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]], 1),
    ], 1)
    return adj / det[:, None, None]


def eigvals_sym_3x3(m):
    """Ascending eigenvalues (M,3) of symmetric 3×3 matrices, closed form (trigonometric), float64."""
    import math

    import torch

    a = m.double()
    q = (a[:, 0, 0] + a[:, 1, 1] + a[:, 2, 2]) / 3.0
    p1 = a[:, 0, 1] ** 2 + a[:, 0, 2] ** 2 + a[:, 1, 2] ** 2
    p2 = (a[:, 0, 0] - q) ** 2 + (a[:, 1, 1] - q) ** 2 + (a[:, 2, 2] - q) ** 2 + 2.0 * p1
    p = torch.sqrt(p2 / 6.0)
    safe_p = torch.where(p > 0, p, torch.ones_like(p))
    b = (a - q[:, None, None] * torch.eye(3, dtype=a.dtype, device=a.device)) / safe_p[:, None, None]
    det_b = (b[:, 0, 0] * (b[:, 1, 1] * b[:, 2, 2] - b[:, 1, 2] * b[:, 2, 1])
             - b[:, 0, 1] * (b[:, 1, 0] * b[:, 2, 2] - b[:, 1, 2] * b[:, 2, 0])
             + b[:, 0, 2] * (b[:, 1, 0] * b[:, 2, 1] - b[:, 1, 1] * b[:, 2, 0]))
    r = (det_b / 2.0).clamp(-1.0, 1.0)
    phi = torch.acos(r) / 3.0
    hi = q + 2.0 * p * torch.cos(phi)
    lo = q + 2.0 * p * torch.cos(phi + 2.0 * math.pi / 3.0)
    mid = 3.0 * q - hi - lo
    return torch.stack([lo, mid, hi], dim=1)


def splat_field(means, covariances, alphas, features, resolution: int = 64, filter_voxels: float = 0.5,
                cutoff_sigma: float = 3.0, max_radius_voxels: int = 6, batch_index=None, batch_size: int = 1,
                chunk_pairs: int | None = None):
    """Density and opacity-weighted feature sums of Gaussians at voxel centres (torch tensors).

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
                w = torch.exp(-0.5 * maha[gi, ki])
                acc.index_add_(0, base_flat[gg] + off_flat[ki], w[:, None] * weighted[gg])
    acc = acc.view(batch_size, np_, np_, np_, f + 1)[:, pad:pad + n, pad:pad + n, pad:pad + n]
    acc = acc.reshape(batch_size, n ** 3, f + 1)
    return acc[..., 0].contiguous(), acc[..., 1:].contiguous()


def grid_channels(density, sums, resolution: int):
    """(B, 2+F, N, N, N) model input from `splat_field` output: [1−exp(−σ), σ>0.01, weighted means]."""
    import torch

    occ = density > OCCUPANCY_THRESHOLD
    means = sums / density.clamp_min(1e-8)[..., None]
    means = torch.where(occ[..., None], means, torch.zeros_like(means))
    chans = torch.cat([(1.0 - torch.exp(-density))[..., None], occ.float()[..., None], means], dim=-1)
    b = density.shape[0]
    n = resolution
    return chans.view(b, n, n, n, -1).permute(0, 4, 1, 2, 3).contiguous(), occ.view(b, n, n, n)


def up_rotation(up: str) -> np.ndarray:
    """Proper rotation (3,3) taking the splat's `up` axis ("z", "y", "-y", "x", "-x", "-z") to +z."""
    mats = {
        "z": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "-z": [[1, 0, 0], [0, -1, 0], [0, 0, -1]],
        "y": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
        "-y": [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
        "x": [[0, 0, -1], [0, 1, 0], [1, 0, 0]],
        "-x": [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],
    }
    if up not in mats:
        raise InputError(f"unknown up axis '{up}' (choose from {', '.join(mats)})")
    return np.array(mats[up], dtype=np.float64)


@dataclass
class GaussianTensors:
    """Per-Gaussian torch tensors of one cloud in its own (world) frame, ready for `prepare_gaussians`.

    means (M,3) and covariances (M,3,3) in the file's length unit, alphas (M,), rgb (M,3) in [0,1],
    sh_energy (M,), extras (M,E) float channels named by the caller.
    """

    means: object
    covariances: object
    alphas: object
    rgb: object
    sh_energy: object
    extras: object


def cloud_tensors(cloud: SplatCloud, extra_names: list[str], device: str = "cpu",
                  rotation: np.ndarray | None = None) -> GaussianTensors:
    """GaussianTensors of `cloud` (optionally rotated by `rotation` (3,3), e.g. `up_rotation`)."""
    import torch

    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)  # noqa: E731
    means = cloud.means.astype(np.float64)
    cov = cloud.covariances()
    if rotation is not None:
        means = means @ rotation.T
        cov = rotation @ cov @ rotation.T
    sh, extras = per_gaussian_channels(cloud, extra_names)
    return GaussianTensors(t(means), t(cov), t(cloud.opacities), t(cloud.rgb()), t(sh), t(extras))


def per_gaussian_channels(cloud: SplatCloud, extra_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """SH view-dependence energy ‖f_rest‖ (N,) and the named extra float channels (N, E); a channel
    the cloud lacks is zero, so one checkpoint reads files with and without it."""
    sh = (np.linalg.norm(cloud.sh_rest.astype(np.float64), axis=1) if cloud.sh_rest.shape[1]
          else np.zeros(len(cloud)))
    extras = np.zeros((len(cloud), len(extra_names)), np.float32)
    for j, name in enumerate(extra_names):
        if name in cloud.extras:
            extras[:, j] = cloud.extras[name]
    return sh.astype(np.float32), extras


def prepare_gaussians(g: GaussianTensors, margin: float = 0.05, box: tuple | None = None):
    """Normalise into the unit cube and build per-Gaussian features (torch, on g's device).

    The transform is the one of `SplatCloud.unit_cube_transform`: isotropic, the longest side of
    the centres' bounding box maps to 1 − 2·margin, centred at 0.5. Returns (means_unit (M,3),
    cov_unit (M,3,3), alphas (M,), features (M, len(BASE_FEATURES)+E), scale, offset (3,)).
    Sizes come from the covariance eigenvalues so they stay right after any rotation/stretch.
    `box` (lo (3,), hi (3,)) replaces the centres' min/max, e.g. a prepared object's robust box.
    """
    import torch

    if box is None:
        lo = g.means.amin(dim=0)
        hi = g.means.amax(dim=0)
    else:
        lo = torch.as_tensor(np.asarray(box[0], np.float32), device=g.means.device)
        hi = torch.as_tensor(np.asarray(box[1], np.float32), device=g.means.device)
    extent = float((hi - lo).max())
    scale = (1.0 - 2.0 * margin) / extent if extent > 0 else 1.0
    offset = (lo + hi) / 2.0
    means = (g.means - offset) * scale + 0.5
    cov = g.covariances * scale ** 2
    evals = eigvals_sym_3x3(cov).clamp_min(1e-30).float()  # ascending, closed form (no solver workspace)
    log_sd = 0.5 * torch.log(evals)
    log_size = (log_sd.mean(dim=1) + 5.0) / 2.0  # ≈ [-1, 1] for unit-cube sizes 1e-4 … 1
    anisotropy = (log_sd[:, 2] - log_sd[:, 0]) / 3.0
    feats = torch.cat([g.rgb, g.alphas[:, None], log_size[:, None], anisotropy[:, None],
                       g.sh_energy[:, None], g.extras], dim=1)
    return means, cov, g.alphas, feats, scale, offset


def feature_grid(cloud: SplatCloud, resolution: int = 64, extra_names: list[str] | None = None,
                 device: str = "cpu", filter_voxels: float = 0.5, margin: float = 0.05,
                 up: "str | np.ndarray" = "z", box: tuple | None = None) -> FeatureGrid:
    """The FeatureGrid of `cloud` (turned z-up, normalised into the unit cube), torch on `device`.

    `extra_names` picks the extra float channels (default: every usable one in the file; a model
    passes the list it was trained with, missing ones become zeros). The grid's `transform` maps
    the z-up-rotated world coordinates into the unit cube (see `grid_coordinates`). `up` is an
    axis name or a unit vector (turned to +z by the smallest rotation); `box` (lo, hi) in the
    rotated frame replaces the centres' min/max for the normalisation.
    """
    if extra_names is None:
        extra_names = extra_feature_names(cloud)
    if isinstance(up, str):
        rot = None if up == "z" else up_rotation(up)
    else:
        from .prepare.updir import rotation_to_z

        rot = rotation_to_z(np.asarray(up, np.float64))
        rot = None if np.allclose(rot, np.eye(3)) else rot
    g = cloud_tensors(cloud, extra_names, device, rot)
    means, cov, alpha, feats, scale, offset = prepare_gaussians(g, margin, box)
    dens, sums = splat_field(means, cov, alpha, feats, resolution, filter_voxels=filter_voxels)
    values, occ = grid_channels(dens, sums, resolution)
    tf = UnitCubeTransform(scale=float(scale), offset=offset.double().cpu().numpy())
    return FeatureGrid(values=values[0].cpu().numpy(), occupancy=occ[0].cpu().numpy(),
                       channels=list(DENSITY_CHANNELS + BASE_FEATURES) + list(extra_names),
                       transform=tf, resolution=resolution,
                       extra={"density": dens[0].view(resolution, resolution, resolution).cpu().numpy(),
                              "means_unit": means.cpu().numpy(), "rotation": rot})
