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
from contextlib import contextmanager
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


def entry_rows(m, xp=None):
    """(nine float64 entry rows a_ij (row 3i+j), array module, back-conversion) of a batch (M,3,3).

    CPU tensors and numpy arrays are computed with numpy (about 5× less CPU than torch's threaded
    element-wise kernels on a busy 2-core machine); CUDA tensors stay in torch, and so do CPU
    tensors when `xp` is torch."""
    import torch

    if isinstance(m, np.ndarray) or (m.device.type == "cpu" and xp is not torch):
        a = np.asarray(m.numpy() if isinstance(m, torch.Tensor) else m).reshape(-1, 9)
        back = torch.from_numpy if isinstance(m, torch.Tensor) else (lambda x: x)
        return [a[:, k].astype(np.float64) for k in range(9)], np, back  # strided reads: no (M,9) transpose
    return list(m.double().reshape(-1, 9).t().contiguous()), torch, (lambda x: x)


def inverse_rows(a: list, xp) -> list:
    """Entry rows of the inverses of the 3×3 matrices with entry rows `a` (adjugate / determinant)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    adj = [c00, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11,
           c01, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12,
           c02, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10]
    return [c / det for c in adj]


def eigval_rows(a: list, xp) -> tuple:
    """(lowest, middle, highest) eigenvalue rows of the symmetric 3×3 matrices with entry rows `a`,
    closed form (trigonometric)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 ** 2 + a02 ** 2 + a12 ** 2
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 ** 2 + b11 ** 2 + b22 ** 2 + 2.0 * p1
    p = xp.sqrt(p2 / 6.0)
    safe_p = xp.where(p > 0, p, 1.0)
    # det(B) of B = (A − qI)/p, expanded along the first row
    det_b = (b00 * (b11 * b22 - a12 * a21) - a01 * (a10 * b22 - a12 * a20) + a02 * (a10 * a21 - b11 * a20)) / safe_p ** 3
    phi = xp.arccos((det_b / 2.0).clip(-1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * xp.cos(phi)
    lo = q + 2.0 * p * xp.cos(phi + 2.0 * math.pi / 3.0)
    return lo, 3.0 * q - hi - lo, hi


def inverse_3x3(m):
    """Inverse of a batch (M,3,3) of symmetric positive-definite matrices by the adjugate formula.

    Closed form in float64: no solver workspace, so it scales to millions of Gaussians on a GPU
    (batched cuSOLVER/cuBLAS calls need workspace that grows with the batch). Entry-wise on
    contiguous rows, several times faster on a CPU than indexing the (M,3,3) tensor.
    """
    if _numpy_blocks(m):
        return _blockwise(inverse_3x3, m, (3, 3))
    a, xp, back = entry_rows(m)
    return back(xp.stack(inverse_rows(a, xp), 1).reshape(-1, 3, 3))


def eigvals_sym_3x3(m):
    """Ascending eigenvalues (M,3) of symmetric 3×3 matrices, closed form (trigonometric), float64."""
    if _numpy_blocks(m):
        return _blockwise(eigvals_sym_3x3, m, (3,))
    a, xp, back = entry_rows(m)
    return back(xp.stack(eigval_rows(a, xp), 1))


NUMPY_BLOCK = 65_536  # matrices per numpy step: float64 temporaries of 0.5 MB stay cache-resident and reuse heap


def _numpy_blocks(m) -> bool:
    """True when `m` (array or CPU tensor) is large enough to be processed in NUMPY_BLOCK slices."""
    import torch

    return len(m) > NUMPY_BLOCK and (isinstance(m, np.ndarray) or m.device.type == "cpu")


def _blockwise(fn, m, tail: tuple):
    """fn over NUMPY_BLOCK slices of a batch of 3×3 matrices, gathered into one float64 result."""
    import torch

    out = np.empty((len(m),) + tail, np.float64)
    for s in range(0, len(m), NUMPY_BLOCK):
        part = fn(m[s:s + NUMPY_BLOCK])
        out[s:s + NUMPY_BLOCK] = part.numpy() if isinstance(part, torch.Tensor) else part
    return torch.from_numpy(out) if isinstance(m, torch.Tensor) else out


def splat_field(means, covariances, alphas, features, resolution: int = 64, filter_voxels: float = 0.5,
                cutoff_sigma: float = 3.0, max_radius_voxels: int = 6, batch_index=None, batch_size: int = 1,
                chunk_pairs: int | None = None):
    """Density and opacity-weighted feature sums of Gaussians at voxel centres (torch tensors).

    means (M,3) in the unit cube, covariances (M,3,3) in unit-cube units², alphas (M,), features
    (M,F). `batch_index` (M,) long puts each Gaussian into one of `batch_size` grids (used by
    training to evaluate several objects in one pass). Returns (density (B,N³), feature sums
    (B,N³,F)); divide the sums by the density for weighted means. All on `means.device`: numpy and
    scipy do the work for CPU tensors, torch for CUDA ones (pixie_gs/field_stencil.py); the plain
    twin it is tested against is `field_reference.splat_field_reference`. `chunk_pairs` bounds the
    candidate (Gaussian, voxel) pairs held at once.
    """
    from .field_stencil import stencil_field

    return stencil_field(means, covariances, alphas, features, resolution, filter_voxels, cutoff_sigma,
                         max_radius_voxels, batch_index, batch_size, chunk_pairs)


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
    if rotation is not None:
        means = means @ np.asarray(rotation, np.float64).T
    sh, extras = per_gaussian_channels(cloud, extra_names)
    return GaussianTensors(t(means), t(rotated_covariances(cloud, rotation)), t(cloud.opacities), t(cloud.rgb()),
                           t(sh), t(extras))


def rotated_covariances(cloud: SplatCloud, rotation: np.ndarray | None = None) -> np.ndarray:
    """(N,3,3) float32 covariances Q R S² Rᵀ Qᵀ of the cloud turned by `rotation` Q (None: identity).

    `cloud.covariances()` (then turned) computed entry by entry in float32 on contiguous rows: within a
    few float32 roundings of the float64 result (~3e-7 of the largest entry), about 10× less time than
    float64 stacked 3×3 matmuls on 1M Gaussians."""
    f32 = np.float32
    q = np.ascontiguousarray(cloud.rotations.T, dtype=f32)
    q = q / np.sqrt((q * q).sum(0, dtype=np.float64)).astype(f32)
    w, x, y, z = q
    r = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    if rotation is not None:
        rot = np.asarray(rotation, np.float64).astype(f32)
        r = [rot[i, 0] * r[j] + rot[i, 1] * r[3 + j] + rot[i, 2] * r[6 + j] for i in range(3) for j in range(3)]
    s2 = np.exp(2 * np.ascontiguousarray(cloud.log_scales.T, dtype=f32))
    rs = [r[3 * i + k] * s2[k] for i in range(3) for k in range(3)]  # (R S²)_ik
    out = np.empty((len(w), 3, 3), f32)
    for i in range(3):
        for j in range(i, 3):
            v = rs[3 * i] * r[3 * j] + rs[3 * i + 1] * r[3 * j + 1] + rs[3 * i + 2] * r[3 * j + 2]
            out[:, i, j] = v
            out[:, j, i] = v
    return out


def per_gaussian_channels(cloud: SplatCloud, extra_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """SH view-dependence energy ‖f_rest‖ (N,) and the named extra float channels (N, E); a channel
    the cloud lacks is zero, so one checkpoint reads files with and without it."""
    rest = cloud.sh_rest
    sh = (np.sqrt(np.einsum("ij,ij->i", rest, rest, dtype=np.float64)) if rest.shape[1]
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
    if g.means.device.type == "cpu":
        return _prepare_gaussians_numpy(g, margin, box)
    return _prepare_gaussians_torch(g, margin, box)


def _prepare_gaussians_torch(g: GaussianTensors, margin: float, box: tuple | None):
    """`prepare_gaussians` in torch on g's device (the CUDA path; tests run it on CPU tensors too)."""
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


def _prepare_gaussians_numpy(g: GaussianTensors, margin: float, box: tuple | None):
    """`prepare_gaussians` for CPU tensors, with numpy (same float32 arithmetic, less CPU than torch's
    threaded element-wise kernels on a busy 2-core machine); returns torch tensors sharing the memory."""
    import torch

    pts = g.means.numpy()
    if box is None:
        lo, hi = pts.min(0), pts.max(0)
    else:
        lo, hi = np.asarray(box[0], np.float32), np.asarray(box[1], np.float32)
    extent = float((hi - lo).max())
    scale = (1.0 - 2.0 * margin) / extent if extent > 0 else 1.0
    offset = (lo + hi) / np.float32(2.0)
    means = (pts - offset) * np.float32(scale) + np.float32(0.5)
    cov = g.covariances.numpy() * np.float32(scale ** 2)
    evals = np.maximum(eigvals_sym_3x3(cov), 1e-30).astype(np.float32)
    log_sd = np.float32(0.5) * np.log(evals)
    feats = np.empty((len(pts), 3 + 4 + g.extras.shape[1]), np.float32)
    feats[:, 0:3] = g.rgb.numpy()
    feats[:, 3] = g.alphas.numpy()
    feats[:, 4] = (log_sd.mean(1) + np.float32(5.0)) / np.float32(2.0)  # ≈ [-1, 1] for unit-cube sizes 1e-4 … 1
    feats[:, 5] = (log_sd[:, 2] - log_sd[:, 0]) / np.float32(3.0)
    feats[:, 6] = g.sh_energy.numpy()
    feats[:, 7:] = g.extras.numpy()
    t = torch.from_numpy
    return t(means), t(cov), g.alphas, t(feats), scale, t(np.asarray(offset, np.float32))


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
    if str(device) == "cpu":
        with small_pages():
            return _feature_grid(cloud, resolution, extra_names, device, filter_voxels, margin, up, box)
    return _feature_grid(cloud, resolution, extra_names, device, filter_voxels, margin, up, box)


@contextmanager
def small_pages():
    """Numpy allocations without transparent-huge-page advice while inside (restored after).

    The field's large temporaries are short-lived; on a shared machine whose memory is fragmented,
    the kernel compacts memory to back each of them with huge pages, which cost more system time than
    the arithmetic (measured: 1M-Gaussian grid 2.0–2.4 s wall with, 2.8 s without this)."""
    core = getattr(np, "_core", None) or np.core
    setter = getattr(core.multiarray, "_set_madvise_hugepage", None)
    if setter is None:
        yield
        return
    previous = setter(False)
    try:
        yield
    finally:
        setter(previous)


def _feature_grid(cloud: SplatCloud, resolution: int, extra_names: list[str] | None, device: str,
                  filter_voxels: float, margin: float, up, box: tuple | None) -> FeatureGrid:
    """`feature_grid`'s work."""
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
