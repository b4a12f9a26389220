"""Per-pixel front-to-back compositing as a Warp kernel (CPU and CUDA from the same code).

One thread per pixel walks its tile's depth-sorted Gaussian list, as the 3DGS CUDA rasteriser
does: α = min(0.99, o · exp(−½ dᵀ Σ₂⁻¹ d)), skip α < 1/255, stop before transmittance < 1e-4.
The lists come from `raster._tile_pairs` (torch); arrays are shared with torch without copies.
"""
from __future__ import annotations

import torch
import warp as wp

from ..devices import init_warp_quietly


MAX_SETS = 4  # colourings composited in one pass (they share every α and transmittance)


@wp.kernel
def _composite(ranges: wp.array(dtype=wp.int32, ndim=2), order: wp.array(dtype=wp.int32),
               mean2d: wp.array(dtype=wp.vec2), conic: wp.array(dtype=wp.vec3),
               opacity: wp.array(dtype=wp.float32), min_power: wp.array(dtype=wp.float32),
               colour: wp.array(dtype=wp.vec3, ndim=2), sets: int,
               tiles_x: int, tile: int, alpha_max: float, alpha_min: float, t_min: float,
               background: wp.vec3, image: wp.array(dtype=wp.vec3, ndim=3),
               trans: wp.array(dtype=wp.float32, ndim=2)):
    row, col = wp.tid()
    t = (row // tile) * tiles_x + col // tile
    px = float(col) + 0.5
    py = float(row) + 0.5
    T = float(1.0)
    c0 = wp.vec3(0.0, 0.0, 0.0)
    c1 = wp.vec3(0.0, 0.0, 0.0)
    c2 = wp.vec3(0.0, 0.0, 0.0)
    c3 = wp.vec3(0.0, 0.0, 0.0)
    for k in range(ranges[t, 0], ranges[t, 1]):
        i = order[k]
        m = mean2d[i]
        q = conic[i]
        dx = px - m[0]
        dy = py - m[1]
        power = -0.5 * (q[0] * dx * dx + q[2] * dy * dy) - q[1] * dx * dy
        if power > 0.0 or power < min_power[i]:  # min_power: where o · exp(power) = 1/255
            continue
        alpha = wp.min(alpha_max, opacity[i] * wp.exp(power))
        if alpha < alpha_min:
            continue
        t_next = T * (1.0 - alpha)
        if t_next < t_min:
            break
        w = alpha * T
        c0 = c0 + colour[i, 0] * w
        if sets > 1:
            c1 = c1 + colour[i, 1] * w
        if sets > 2:
            c2 = c2 + colour[i, 2] * w
        if sets > 3:
            c3 = c3 + colour[i, 3] * w
        T = t_next
    image[0, row, col] = c0 + background * T
    if sets > 1:
        image[1, row, col] = c1 + background * T
    if sets > 2:
        image[2, row, col] = c2 + background * T
    if sets > 3:
        image[3, row, col] = c3 + background * T
    trans[row, col] = T


def composite(ranges: torch.Tensor, order: torch.Tensor, mean2d: torch.Tensor, conic: torch.Tensor,
              opacity: torch.Tensor, colours: torch.Tensor, width: int, height: int, tiles_x: int,
              tile: int, alpha_max: float, alpha_min: float, t_min: float,
              background: tuple[float, float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """(images (M,H,W,3), transmittance (H,W)) as torch tensors on the inputs' device, for M ≤ 4
    colourings at once: colours (N,M,3) (or (N,3) for one).

    ranges (n_tiles, 2) int32: [start, end) of each tile in `order` (int32 Gaussian indices)."""
    init_warp_quietly()
    dev = colours.device
    wdev = "cpu" if dev.type == "cpu" else f"cuda:{dev.index or 0}"
    if colours.dim() == 2:
        colours = colours[:, None, :]
    sets = colours.shape[1]
    if not 1 <= sets <= MAX_SETS:
        raise ValueError(f"composite takes 1..{MAX_SETS} colourings at once, got {sets}")
    image = torch.empty(sets, height, width, 3, dtype=torch.float32, device=dev)
    trans = torch.empty(height, width, dtype=torch.float32, device=dev)
    keep = []  # contiguous copies stay alive until the kernel has run

    def w(x: torch.Tensor, dtype):
        keep.append(x.contiguous())
        return wp.from_torch(keep[-1], dtype=dtype)

    min_power = torch.log(alpha_min / opacity.clamp(min=1e-30))
    # on CUDA the kernel joins torch's current stream, so it runs after the torch work that made
    # its inputs and before any torch work that reads its outputs
    stream = None if wdev == "cpu" else wp.stream_from_torch(torch.cuda.current_stream(dev))
    wp.launch(_composite, dim=(height, width), device=wdev, stream=stream, inputs=[
        w(ranges, wp.int32), w(order, wp.int32), w(mean2d, wp.vec2), w(conic, wp.vec3),
        w(opacity, wp.float32), w(min_power, wp.float32), w(colours.float(), wp.vec3), int(sets),
        int(tiles_x), int(tile), float(alpha_max), float(alpha_min), float(t_min),
        wp.vec3(*[float(v) for v in background]), w(image, wp.vec3), w(trans, wp.float32)])
    if stream is not None:
        wp.synchronize_stream(stream)  # the contiguous copies in `keep` may be freed after this
    return image, trans
