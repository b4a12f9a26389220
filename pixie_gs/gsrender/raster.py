"""The fast 3D Gaussian splat rasteriser: EWA projection, SH colour, tile-sorted front-to-back
alpha compositing, in torch (the same code on CPU and CUDA).

Follows the 3DGS conventions (Kerbl et al. 2023): 2D covariance J W Σ Wᵀ Jᵀ + 0.3 px² (a
low-pass filter so every splat covers about a pixel), α = min(0.99, o · exp(−½ dᵀ Σ₂⁻¹ d)),
splats with α < 1/255 skipped at a pixel, Gaussians sorted by view depth, and a pixel stops at
the splat that would bring its transmittance below 1e-4. The image is cut into 16×16 tiles;
each Gaussian is listed in every tile its α ≥ 1/255 footprint touches, and the (tile, depth)
sorted list is composited in vectorised chunks: a segmented cumulative sum of log(1 − α) gives
every splat's transmittance at every pixel of its tile at once, so no per-pixel loop runs in
Python. `pixie_gs.gsrender.reference` is the slow per-pixel definition this must match.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from . import sh
from .camera import Camera

TILE = 16
LOW_PASS_PX2 = 0.3  # added to the 2D covariance's diagonal (px²)
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4  # a pixel is done once its transmittance would fall below this
FOV_GUARD = 0.3  # tan-space margin beyond the image where the projection Jacobian is clamped (3DGS 1.3×)


@dataclass
class Gaussians:
    """N Gaussians as torch tensors on one device: centres (N,3), std-devs (N,3), unit
    quaternions w,x,y,z (N,4), opacities in [0,1] (N,), SH coefficients (N,K,3), K = 1/4/9/16."""

    means: torch.Tensor
    scales: torch.Tensor
    quats: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor

    @classmethod
    def from_cloud(cls, cloud, device: str | torch.device = "cpu") -> "Gaussians":
        """From a SplatCloud (float32 on `device`)."""
        def t(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(a, np.float32), device=device)

        return cls(t(cloud.means), t(cloud.scales), t(cloud.quats), t(cloud.opacities),
                   t(sh.coefficients(cloud.sh_dc, cloud.sh_rest)))

    def with_means(self, means: np.ndarray | torch.Tensor) -> "Gaussians":
        return Gaussians(torch.as_tensor(means, dtype=torch.float32, device=self.means.device),
                         self.scales, self.quats, self.opacities, self.sh)

    def __len__(self) -> int:
        return int(self.means.shape[0])


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities for one camera (torch, on the Gaussians' device)."""

    mean2d: torch.Tensor  # (N,2) px
    conic: torch.Tensor  # (N,3) inverse 2D covariance (a, b, c): [[a, b], [b, c]] (1/px²)
    depth: torch.Tensor  # (N,) view-space z
    radius: torch.Tensor  # (N,) px, bound of the α ≥ 1/255 footprint; 0 = not drawn
    opacity: torch.Tensor  # (N,)
    extent: torch.Tensor  # (N,2) px, half width and height of that footprint's bounding box


def covariances3d(scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """Σ = R S Sᵀ Rᵀ (N,3,3) from std-devs (N,3) and unit quaternions w,x,y,z (N,4)."""
    w, x, y, z = quats.unbind(-1)
    R = torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)
    M = R * scales[:, None, :]
    return M @ M.transpose(1, 2)


def project(g: Gaussians, cam: Camera) -> Projected:
    """EWA projection of every Gaussian into `cam` (radius 0 for those not drawn)."""
    dev = g.means.device
    R = torch.as_tensor(np.asarray(cam.R, np.float32), device=dev)
    t = torch.as_tensor(np.asarray(cam.t, np.float32), device=dev)
    p = g.means @ R.T + t
    x, y, z = p.unbind(-1)
    in_front = z > cam.near
    zs = torch.where(in_front, z, torch.ones_like(z))
    tan_x, tan_y = 0.5 * cam.width / cam.fx, 0.5 * cam.height / cam.fy
    lim_x_neg, lim_x_pos = cam.cx / cam.fx + FOV_GUARD * tan_x, (cam.width - cam.cx) / cam.fx + FOV_GUARD * tan_x
    lim_y_neg, lim_y_pos = cam.cy / cam.fy + FOV_GUARD * tan_y, (cam.height - cam.cy) / cam.fy + FOV_GUARD * tan_y
    xc = (x / zs).clamp(-lim_x_neg, lim_x_pos) * zs
    yc = (y / zs).clamp(-lim_y_neg, lim_y_pos) * zs
    zero = torch.zeros_like(zs)
    J = torch.stack([cam.fx / zs, zero, -cam.fx * xc / zs ** 2,
                     zero, cam.fy / zs, -cam.fy * yc / zs ** 2], dim=-1).reshape(-1, 2, 3)
    T = J @ R  # (N,2,3): world -> screen Jacobian
    cov2 = T @ covariances3d(g.scales, g.quats) @ T.transpose(1, 2)
    a = cov2[:, 0, 0] + LOW_PASS_PX2
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + LOW_PASS_PX2
    det = a * c - b * b
    ok = in_front & (det > 0) & (g.opacities >= ALPHA_MIN) & torch.isfinite(det)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    conic = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)
    mid = 0.5 * (a + c)
    lam_max = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
    cutoff = 2.0 * torch.log(torch.clamp(g.opacities * 255.0, min=1.0))  # α ≥ 1/255 inside d² ≤ cutoff
    radius = torch.where(ok, torch.sqrt(cutoff * lam_max) + 1.0, torch.zeros_like(a))
    # the ellipse dᵀ Σ₂⁻¹ d ≤ cutoff spans ±sqrt(cutoff · Σ₂[k,k]) along axis k
    extent = torch.stack([torch.sqrt(cutoff * a), torch.sqrt(cutoff * c)], dim=-1) + 1.0
    mean2d = torch.stack([cam.fx * x / zs + cam.cx, cam.fy * y / zs + cam.cy], dim=-1)
    return Projected(mean2d=mean2d, conic=conic, depth=z, radius=radius, opacity=g.opacities,
                     extent=torch.where(ok[:, None], extent, torch.zeros_like(extent)))


def view_colours(g: Gaussians, cam: Camera) -> torch.Tensor:
    """RGB (N,3) ≥ 0 of each Gaussian seen from the camera centre (SH of its degree)."""
    degree = sh.degree_of(g.sh.shape[1])
    centre = torch.as_tensor(cam.centre, dtype=torch.float32, device=g.means.device)
    d = g.means - centre
    d = d / torch.clamp(torch.linalg.norm(d, dim=-1, keepdim=True), min=1e-12)
    basis = torch.stack(sh.basis(d[:, 0], d[:, 1], d[:, 2], degree), dim=-1)  # (N,K)
    return torch.clamp(torch.einsum("nk,nkc->nc", basis, g.sh) + 0.5, min=0.0)


def _tile_pairs(pr: Projected, tiles_x: int, tiles_y: int, tile_px: int = TILE) -> tuple[torch.Tensor, torch.Tensor]:
    """(Gaussian index, tile id) of every Gaussian-tile overlap, sorted by tile then depth."""
    dev = pr.depth.device
    drawn = torch.nonzero(pr.radius > 0).squeeze(1)
    if len(drawn) == 0:
        empty = torch.zeros(0, dtype=torch.long, device=dev)
        return empty, empty
    m, e = pr.mean2d[drawn], pr.extent[drawn]
    # pixel i (centre i + 0.5) can be touched when |i + 0.5 − m| ≤ extent
    x0 = torch.clamp(torch.floor((m[:, 0] - e[:, 0] - 0.5) / tile_px), 0, tiles_x).long()
    x1 = torch.clamp(torch.floor((m[:, 0] + e[:, 0] - 0.5) / tile_px) + 1, 0, tiles_x).long()
    y0 = torch.clamp(torch.floor((m[:, 1] - e[:, 1] - 0.5) / tile_px), 0, tiles_y).long()
    y1 = torch.clamp(torch.floor((m[:, 1] + e[:, 1] - 0.5) / tile_px) + 1, 0, tiles_y).long()
    w, h = (x1 - x0).clamp(min=0), (y1 - y0).clamp(min=0)
    count = w * h
    keep = count > 0
    drawn, x0, y0, w, count = drawn[keep], x0[keep], y0[keep], w[keep], count[keep]
    if len(drawn) == 0:
        empty = torch.zeros(0, dtype=torch.long, device=dev)
        return empty, empty
    # depth rank of each listed Gaussian (ties: lower index first)
    order = torch.argsort(pr.depth[drawn], stable=True)
    rank = torch.empty_like(order)
    rank[order] = torch.arange(len(order), device=dev)
    owner = torch.repeat_interleave(torch.arange(len(drawn), device=dev), count)
    first = torch.cumsum(count, 0) - count
    k = torch.arange(len(owner), device=dev) - first[owner]
    tile = (y0[owner] + k // w[owner]) * tiles_x + x0[owner] + k % w[owner]
    key = tile * len(drawn) + rank[owner]
    key, perm = torch.sort(key)
    return drawn[owner[perm]], key // len(drawn)


def rasterize(pr: Projected, colours: torch.Tensor, width: int, height: int,
              background: tuple[float, float, float] = (1.0, 1.0, 1.0), backend: str = "warp",
              chunk_pairs: int | None = None,
              pairs: tuple[torch.Tensor, torch.Tensor] | None = None,
              tile_px: int = TILE) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite projected Gaussians with per-Gaussian colours (N,3) front to back.

    Returns (image (H,W,3) float in [0, ∞) with the background blended in, transmittance (H,W)).
    With colours (N,M,3) (M ≤ 4 colourings, warp backend) the image is (H,W,M,3).
    backend: "warp" (a per-pixel kernel, fast on CPU and GPU) or "torch" (vectorised tensors, no
    kernel compilation; chunk_pairs Gaussian-tile pairs per step, memory ≈ 60 B × 256 × chunk).
    pairs: the sorted (Gaussian, tile) lists of `pr` when already made (several colourings of one view).
    tile_px: tile side (px); the image does not depend on it, only the work does.
    """
    dev = colours.device
    channels = colours.shape[1]
    tiles_x, tiles_y = -(-width // tile_px), -(-height // tile_px)
    n_tiles = tiles_x * tiles_y
    gid, tile = _tile_pairs(pr, tiles_x, tiles_y, tile_px) if pairs is None else pairs
    if backend == "warp":
        from .composite import composite

        counts = torch.bincount(tile, minlength=n_tiles)
        ends = torch.cumsum(counts, 0)
        ranges = torch.stack([ends - counts, ends], dim=1).to(torch.int32)
        images, trans = composite(ranges, gid.to(torch.int32), pr.mean2d, pr.conic, pr.opacity, colours.float(),
                                  width, height, tiles_x, tile_px, ALPHA_MAX, ALPHA_MIN, T_MIN, background)
        return (images[0] if colours.dim() == 2 else images.permute(1, 2, 0, 3)), trans
    if backend != "torch":
        raise ValueError(f"unknown rasteriser backend {backend!r} (warp or torch)")
    if chunk_pairs is None:
        chunk_pairs = 4096 if dev.type == "cpu" else 65536
    local = torch.arange(tile_px * tile_px, device=dev)
    lx = (local % tile_px).to(torch.float32) + 0.5
    ly = (local // tile_px).to(torch.float32) + 0.5
    acc = torch.zeros(n_tiles, tile_px * tile_px, channels, device=dev)
    log_t_all = torch.zeros(n_tiles, tile_px * tile_px, dtype=torch.float64, device=dev)  # every splat so far
    log_t_kept = torch.zeros(n_tiles, tile_px * tile_px, dtype=torch.float64, device=dev)  # splats composited
    done = torch.zeros(n_tiles, dtype=torch.bool, device=dev)
    log_t_min = math.log(T_MIN)
    start = 0
    while start < len(gid):
        g, tl = gid[start:start + chunk_pairs], tile[start:start + chunk_pairs]
        start += chunk_pairs
        live = ~done[tl]  # tiles whose every pixel has finished need no more work
        if not bool(live.all()):
            g, tl = g[live], tl[live]
            if len(g) == 0:
                continue
        px = (tl % tiles_x).to(torch.float32)[:, None] * tile_px + lx
        py = (tl // tiles_x).to(torch.float32)[:, None] * tile_px + ly
        dx = px - pr.mean2d[g, 0:1]
        dy = py - pr.mean2d[g, 1:2]
        con = pr.conic[g]
        power = -0.5 * (con[:, 0:1] * dx * dx + con[:, 2:3] * dy * dy) - con[:, 1:2] * dx * dy
        alpha = torch.clamp(pr.opacity[g, None] * torch.exp(power), max=ALPHA_MAX)
        alpha = torch.where((alpha >= ALPHA_MIN) & (power <= 0), alpha, torch.zeros_like(alpha))
        log1m = torch.log1p(-alpha.double())
        # segmented (per tile) inclusive cumulative sum, continued from earlier chunks
        cum = torch.cumsum(log1m, 0)
        is_start = torch.ones(len(tl), dtype=torch.bool, device=dev)
        is_start[1:] = tl[1:] != tl[:-1]
        seg = torch.cumsum(is_start.long(), 0) - 1
        seg_first = torch.nonzero(is_start).squeeze(1)
        before_seg = (cum - log1m)[seg_first]  # exclusive sum at each segment's first pair
        log_t_after = cum - before_seg[seg] + log_t_all[tl]
        kept = (log_t_after >= log_t_min) & (alpha > 0)
        weight = torch.where(kept, alpha * torch.exp(log_t_after - log1m).float(), torch.zeros_like(alpha))
        acc.index_add_(0, tl, weight[:, :, None] * colours[g][:, None, :])
        log_t_kept.index_add_(0, tl, torch.where(kept, log1m, torch.zeros_like(log1m)))
        seg_last = torch.cat([seg_first[1:] - 1, torch.tensor([len(tl) - 1], device=dev)])
        log_t_all[tl[seg_last]] = log_t_after[seg_last]
        done[tl[seg_last]] = (log_t_after[seg_last] < log_t_min).all(dim=1)
    trans = torch.exp(log_t_kept).float()
    bg = torch.as_tensor(background, dtype=torch.float32, device=dev)[:channels]
    image = acc + trans[:, :, None] * bg
    image = image.reshape(tiles_y, tiles_x, tile_px, tile_px, channels).permute(0, 2, 1, 3, 4)
    image = image.reshape(tiles_y * tile_px, tiles_x * tile_px, channels)[:height, :width]
    trans = trans.reshape(tiles_y, tiles_x, tile_px, tile_px).permute(0, 2, 1, 3).reshape(tiles_y * tile_px, tiles_x * tile_px)
    return image, trans[:height, :width]


def render(g: Gaussians, cam: Camera, colours: torch.Tensor | np.ndarray | None = None,
           background: tuple[float, float, float] = (1.0, 1.0, 1.0), backend: str = "warp") -> torch.Tensor:
    """One image (H,W,3) float in [0,1] of the Gaussians seen by `cam`; colours (N,3) in [0,1]
    replace the SH colour (e.g. material or log E colours), None = the view-dependent SH colour."""
    return render_many(g, cam, [colours], background, backend)[0]


def render_many(g: Gaussians, cam: Camera, colour_sets: list, background: tuple[float, float, float] = (1.0, 1.0, 1.0),
                backend: str = "warp", tile_px: int | None = None) -> list[torch.Tensor]:
    """Images (H,W,3) in [0,1] of one view, one per colouring in `colour_sets` (None = SH colour),
    projecting and sorting once. On CPU torch runs single-threaded here: these element-wise steps
    gain little from threads, and on a busy shared CPU extra threads cost several times more."""
    dev = g.means.device
    threads = torch.get_num_threads()
    if dev.type == "cpu":
        torch.set_num_threads(1)
    try:
        pr = project(g, cam)
        tile_px = tile_px or TILE
        tiles_x, tiles_y = -(-cam.width // tile_px), -(-cam.height // tile_px)
        pairs = _tile_pairs(pr, tiles_x, tiles_y, tile_px)
        rgbs = [view_colours(g, cam) if colours is None else
                torch.as_tensor(np.asarray(colours, np.float32) if isinstance(colours, np.ndarray) else colours,
                                dtype=torch.float32, device=dev) for colours in colour_sets]
        out = []
        if backend == "warp":  # up to MAX_SETS colourings per compositing pass
            from .composite import MAX_SETS

            for k in range(0, len(rgbs), MAX_SETS):
                group = torch.stack(rgbs[k:k + MAX_SETS], dim=1)
                images, _ = rasterize(pr, group, cam.width, cam.height, background, backend=backend, pairs=pairs,
                                      tile_px=tile_px)
                out += [torch.clamp(images[:, :, j], 0.0, 1.0) for j in range(group.shape[1])]
            return out
        for rgb in rgbs:
            image, _ = rasterize(pr, rgb, cam.width, cam.height, background, backend=backend, pairs=pairs,
                                      tile_px=tile_px)
            out.append(torch.clamp(image, 0.0, 1.0))
        return out
    finally:
        torch.set_num_threads(threads)
