"""A small software point-splat renderer for previews, demo strips and diagnose plots.

Orthographic view of coloured points from an azimuth/elevation around the splat's up axis,
fitted to given bounds (fixed bounds keep animation frames steady), drawn as round discs with a
z-buffer (the point nearest the camera wins each pixel). Pure vectorised numpy, no GPU or
rerun; pictures are saved atomically as PNG or GIF, several views joined by `contact_sheet`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path

MAX_AUTO_RADIUS_FRACTION = 1 / 32  # automatic disc radius is at most this share of the image side
# Automatic disc radius / median nearest-neighbour distance. Random surface samples have a median
# neighbour distance ≈ 0.47 × their spacing sqrt(area / n); discs of radius ≈ 1 spacing leave
# only ~5 % of a surface seen face-on uncovered (Poisson coverage 1 − exp(−π r² density)).
AUTO_RADIUS_PER_NN_DISTANCE = 2.0
FIT_MARGIN_FRACTION = 0.05  # blank border kept around the fitted bounds
LABEL_HEIGHT_PX = 16


def up_frame(up: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(azimuth-0 axis, azimuth-90 axis, up axis), right-handed, for an up axis like "z" or "-y"."""
    text = up.strip().lower()
    sign = -1.0 if text.startswith("-") else 1.0
    axis = text.lstrip("+-")
    if axis not in ("x", "y", "z"):
        raise ValueError(f"up axis must be one of x, y, z, -x, -y, -z (got {up!r})")
    k = "xyz".index(axis)
    u = np.zeros(3)
    u[k] = sign
    a = np.zeros(3)
    a[(k + 1) % 3] = 1.0  # the next axis in cyclic order
    return a, np.cross(u, a), u


def view_basis(azimuth_deg: float, elevation_deg: float, up: str = "z") -> np.ndarray:
    """Rows (screen right, screen up, towards the camera) of an orthographic camera (3,3)."""
    a, b, u = up_frame(up)
    az = np.radians(azimuth_deg)
    el = np.radians(np.clip(elevation_deg, -89.9, 89.9))
    to_camera = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * u
    forward = -to_camera
    right = np.cross(forward, u)
    right /= np.linalg.norm(right)
    screen_up = np.cross(right, forward)
    return np.stack([right, screen_up, to_camera])


def typical_neighbour_distance(points: np.ndarray, sample: int = 2000, seed: int = 0) -> float:
    """Median distance from a point to its nearest neighbour (from up to `sample` points), 0 if < 2."""
    if len(points) < 2:
        return 0.0
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    probe = points if len(points) <= sample else points[rng.choice(len(points), sample, replace=False)]
    distance, _ = cKDTree(points).query(probe, k=2)
    return float(np.median(distance[:, 1]))


def _disc_offsets(radius: int) -> tuple[np.ndarray, np.ndarray]:
    d = np.arange(-radius, radius + 1)
    dx, dy = np.meshgrid(d, d, indexing="xy")
    return dx.ravel(), dy.ravel()


def render_points(means: np.ndarray, rgb: np.ndarray, *, size: tuple[int, int] = (256, 256),
                  azimuth_deg: float = 30.0, elevation_deg: float = 20.0, up: str = "z",
                  radius_px: float | np.ndarray | None = None,
                  background: tuple[float, float, float] = (1.0, 1.0, 1.0),
                  bounds: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Render points (N,3) with colours (N,3) (or one (3,) for all) in [0,1] to uint8 (H, W, 3).

    size: (W, H) px. bounds: (min (3,), max (3,)) box fitted into the view (default: the
    points' own bounds); its centre lands at the image centre. radius_px: disc radius in px,
    one value or one per point (default: twice the points' median nearest-neighbour distance,
    so that sampled surfaces look closed from every side).
    """
    width, height = int(size[0]), int(size[1])
    image = np.empty((height, width, 3), np.uint8)
    image[:] = np.round(np.clip(np.asarray(background, np.float64), 0, 1) * 255).astype(np.uint8)
    means = np.asarray(means, np.float64).reshape(-1, 3)
    rgb = np.broadcast_to(np.asarray(rgb, np.float64), means.shape)  # (3,) colours every point
    colors = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    finite = np.isfinite(means).all(axis=1)
    if len(means) == 0 or not finite.any():
        return image
    if bounds is None:
        lo, hi = means[finite].min(axis=0), means[finite].max(axis=0)
    else:
        lo, hi = np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)
    basis = view_basis(azimuth_deg, elevation_deg, up)
    centre = (lo + hi) / 2.0
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    half = np.abs((corners - centre) @ basis[:2].T).max(axis=0)  # half extents on screen (x, y)
    usable = (1.0 - 2.0 * FIT_MARGIN_FRACTION) * np.array([width, height]) / 2.0
    with np.errstate(divide="ignore"):
        px_per_unit = float(np.min(np.where(half > 0, usable / np.maximum(half, 1e-300), np.inf)))
    if not np.isfinite(px_per_unit):
        px_per_unit = 1.0  # a single point (or all on one spot): any scale will do

    screen = (means - centre) @ basis.T
    col = width / 2.0 + screen[:, 0] * px_per_unit
    row = height / 2.0 - screen[:, 1] * px_per_unit
    depth = screen[:, 2]  # larger = nearer the camera

    n = len(means)
    if radius_px is None:
        auto = AUTO_RADIUS_PER_NN_DISTANCE * typical_neighbour_distance(means[finite]) * px_per_unit
        radii = np.full(n, np.clip(auto, 1.5, max(1.5, min(width, height) * MAX_AUTO_RADIUS_FRACTION)))
    else:
        radii = np.broadcast_to(np.asarray(radius_px, np.float64), (n,)).copy()
    radii = np.minimum(radii, max(width, height) / 2.0)  # bounds the work per disc
    keep = finite & (radii >= 0)
    keep &= (col > -radii - 1) & (col < width + radii + 1) & (row > -radii - 1) & (row < height + radii + 1)
    index = np.flatnonzero(keep)
    if len(index) == 0:
        return image
    near_first = index[np.argsort(-depth[index], kind="stable")]
    rank_of = np.empty(n, np.int64)
    rank_of[near_first] = np.arange(len(near_first))

    centre_col = np.floor(col).astype(np.int64)
    centre_row = np.floor(row).astype(np.int64)
    pixel_parts, rank_parts = [], []
    whole = np.ceil(radii[near_first]).astype(np.int64)
    for r_int in np.unique(whole):
        pts = near_first[whole == r_int]
        dx, dy = _disc_offsets(int(r_int))
        inside = (dx[None, :] ** 2 + dy[None, :] ** 2) <= radii[pts, None] ** 2 + 1e-9
        cc = centre_col[pts, None] + dx[None, :]
        rr = centre_row[pts, None] + dy[None, :]
        inside &= (cc >= 0) & (cc < width) & (rr >= 0) & (rr < height)
        pixel_parts.append((rr * width + cc)[inside])
        rank_parts.append(np.broadcast_to(rank_of[pts, None], inside.shape)[inside])
    pixels = np.concatenate(pixel_parts)
    ranks = np.concatenate(rank_parts)
    keys = np.sort(pixels * len(near_first) + ranks)  # per pixel, the nearest point comes first
    pixel_sorted = keys // len(near_first)
    first = np.empty(len(keys), bool)
    first[:1] = True
    first[1:] = pixel_sorted[1:] != pixel_sorted[:-1]
    winners = near_first[keys[first] % len(near_first)]
    image.reshape(-1, 3)[pixel_sorted[first]] = colors[winners]
    return image


def material_panels(cloud, true_id: np.ndarray, predicted_id: np.ndarray, title: str, predicted_label: str,
                    size: tuple[int, int] = (220, 220)) -> tuple[list[np.ndarray], list[str]]:
    """Three views of one splat for a contact sheet: base colour, true and predicted material class
    (`materials.MATERIAL_COLORS`), labelled `title: RGB`, `true material` and `predicted_label`."""
    from .materials import MATERIAL_COLORS

    bounds = cloud.bounds()
    images = [render_points(cloud.means, colours, size=size, bounds=bounds)
              for colours in (cloud.rgb(), MATERIAL_COLORS[true_id], MATERIAL_COLORS[predicted_id])]
    return images, [f"{title}: RGB", "true material", predicted_label]


def contact_sheet(images: list[np.ndarray], labels: list[str], columns: int,
                  background: tuple[int, int, int] = (255, 255, 255)) -> np.ndarray:
    """Tile images (H,W,3 uint8) into a grid, each with its text label above it (uint8 image).

    Every cell is as large as the largest image plus a label strip of LABEL_HEIGHT_PX pixels.
    """
    from PIL import Image, ImageDraw, ImageFont

    if not images:
        raise ValueError("contact_sheet needs at least one image")
    if len(labels) != len(images):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    columns = max(1, min(int(columns), len(images)))
    rows = -(-len(images) // columns)
    cell_h = max(im.shape[0] for im in images) + LABEL_HEIGHT_PX
    cell_w = max(im.shape[1] for im in images)
    sheet = Image.new("RGB", (columns * cell_w, rows * cell_h), tuple(background))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default()
    for k, (im, label) in enumerate(zip(images, labels)):
        x0, y0 = (k % columns) * cell_w, (k // columns) * cell_h
        draw.text((x0 + 3, y0 + 2), str(label), fill=(0, 0, 0), font=font)
        sheet.paste(Image.fromarray(_as_rgb_uint8(im)), (x0, y0 + LABEL_HEIGHT_PX))
    return np.asarray(sheet, np.uint8).copy()


def _as_rgb_uint8(image: np.ndarray) -> np.ndarray:
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        arr = np.round(np.clip(arr.astype(np.float64), 0, 1) * 255).astype(np.uint8)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    return np.ascontiguousarray(arr[:, :, :3])


def save_png(image: np.ndarray, path: str | Path) -> None:
    """Write an image (H,W,3 uint8, or float in [0,1]) as PNG, atomically."""
    from PIL import Image

    with atomic_path(path, suffix=".png.tmp") as tmp:
        Image.fromarray(_as_rgb_uint8(image)).save(tmp, format="PNG")


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float = 10.0) -> None:
    """Write equally sized frames (H,W,3) as a looping GIF at `fps` frames per second, atomically."""
    from PIL import Image

    if not frames:
        raise ValueError("save_gif needs at least one frame")
    shapes = {np.asarray(f).shape[:2] for f in frames}
    if len(shapes) != 1:
        raise ValueError(f"GIF frames differ in size: {sorted(shapes)}")
    pictures = [Image.fromarray(_as_rgb_uint8(f)) for f in frames]
    with atomic_path(path, suffix=".gif.tmp") as tmp:
        pictures[0].save(tmp, format="GIF", save_all=True, append_images=pictures[1:],
                         duration=max(int(round(1000.0 / fps)), 10), loop=0)
