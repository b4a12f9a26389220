"""Turn a triangle mesh into a 3D Gaussian splat (`pixie convert` and the dataset generator).

Surface Gaussians are area-weighted random samples of the triangles: flat discs lying in the
surface (rotation from the face's tangent frame; two tangential std-devs about the sample spacing,
the normal std-dev a fraction of that), coloured from the mesh's base-colour texture (bilinear
texel lookup at the interpolated UV, times the material's colour factor), its vertex colours or
its face colours. With `fill`, isotropic Gaussians are added inside a watertight mesh so that a
simulator has particles throughout the solid; each takes the colour of the nearest surface
sample. All randomness comes from one `numpy.random.Generator`, so a seed fixes the output.
Lengths are in the mesh's own unit (metres when the mesh is in metres).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError, require_file
from .progress import progress
from .splat import SplatCloud, rgb_to_sh_dc, rotmat_to_quat

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off")
# Tangential std-dev relative to the mean sample spacing sqrt(area / n). 0.7 ≈ the mean distance
# to the 3 nearest neighbours of uniform random points on a surface, the usual 3DGS initial scale.
TANGENT_SCALE_RATIO = 0.7
FILL_SCALE_RATIO = 0.7  # interior std-dev relative to the interior spacing (volume / n)^(1/3)
DEFAULT_GREY = 0.7  # colour of meshes that carry none


# ---------------------------------------------------------------------------------------- loading
def load_mesh(path: str | Path) -> "trimesh.Trimesh":  # noqa: F821 (trimesh imported lazily)
    """Read any trimesh-loadable mesh file; scenes are flattened into one mesh with their transforms.

    Raises InputError (file name + problem) for missing, unreadable or face-less files.
    """
    import trimesh

    path = require_file(path, "a mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"unsupported mesh type '{path.suffix}' (use {', '.join(MESH_SUFFIXES)})", path)
    _refuse_undecodable_gltf(path)
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        text = str(exc).splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, ImportError):  # trimesh reaches for an optional text-encoding detector on garbage
            text = f"contents are not a readable {path.suffix.lower()} file (binary garbage or an unknown text encoding)"
        raise InputError(f"cannot read mesh ({text[:200]})", path) from None
    _refuse_malformed_geometry(loaded, path)
    meshes = _triangle_meshes(loaded)
    if not meshes:
        raise InputError("has no triangle faces (a point cloud or empty file? convert needs a mesh)", path)
    mesh = meshes[0] if len(meshes) == 1 else _join_keeping_colour_sources(meshes)
    if not np.isfinite(np.asarray(mesh.vertices)).all():
        raise InputError("has non-finite (NaN/inf) vertex positions", path)
    if _face_areas(mesh).sum() <= 0:
        raise InputError("has zero surface area (all triangles degenerate)", path)
    mesh.metadata["source"] = str(path)
    return mesh


# glTF extensions that replace the geometry with a compressed stream trimesh cannot decode; a file that only
# *uses* one keeps plain fallback geometry, so only `extensionsRequired` is refused.
UNDECODABLE_GLTF_EXTENSIONS = ("KHR_draco_mesh_compression", "EXT_meshopt_compression")


def _gltf_required_extensions(path: Path) -> list[str]:
    """`extensionsRequired` of a .glb / .gltf file's JSON (empty when there is none or it cannot be read: the
    loader then reports the real problem)."""
    import json
    import struct

    try:
        with open(path, "rb") as f:
            head = f.read(20)
            if head[:4] == b"glTF":
                length, kind = struct.unpack("<I4s", head[12:20])
                if kind != b"JSON" or length > 64 * 2**20:
                    return []
                text = f.read(length)
            else:
                text = head + f.read(64 * 2**20)
        required = json.loads(text).get("extensionsRequired", [])
    except (OSError, ValueError, struct.error, AttributeError):
        return []
    return [str(e) for e in required] if isinstance(required, list) else []


def _refuse_undecodable_gltf(path: Path) -> None:
    """One clear error for compressed glTF geometry (Draco, meshopt), which trimesh would otherwise read as
    degenerate triangles ("zero surface area")."""
    if path.suffix.lower() not in (".glb", ".gltf"):
        return
    compressed = [e for e in _gltf_required_extensions(path) if e in UNDECODABLE_GLTF_EXTENSIONS]
    if compressed:
        raise InputError(f"its geometry is compressed with {', '.join(compressed)}, which pixie cannot decode: "
                         "export it again without mesh compression (e.g. Blender's glTF export with "
                         "'Compression' off)", path)


def _refuse_malformed_geometry(loaded, path: Path) -> None:
    """InputError when a mesh's vertices are not 3-D points or a triangle names a vertex the mesh does not
    have (a damaged file): trimesh loads such files and fails later, with an IndexError or an AxisError, when
    it first looks the corners up."""
    import trimesh

    geometries = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
    for geometry in geometries:
        if not isinstance(geometry, trimesh.Trimesh) or not len(geometry.faces):
            continue
        vertices, faces = np.asarray(geometry.vertices), np.asarray(geometry.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise InputError(f"vertex positions have shape {vertices.shape}, not (N, 3)", path)
        bad = (faces < 0) | (faces >= len(vertices))
        if bad.any():
            row = int(np.argmax(bad.any(axis=1)))
            raise InputError(f"triangle {row} refers to vertex {int(faces[row][bad[row]][0])}, but the mesh has "
                             f"{len(vertices)} vertices (a damaged index buffer)", path)


def _triangle_meshes(loaded) -> list:
    """Every Trimesh with faces in `loaded` (a Trimesh or a Scene), in world coordinates."""
    import trimesh

    if isinstance(loaded, trimesh.Trimesh):
        return [loaded] if len(loaded.faces) else []
    if not isinstance(loaded, trimesh.Scene):
        return []
    meshes = []
    for node in loaded.graph.nodes_geometry:
        transform, geometry_name = loaded.graph[node]
        geometry = loaded.geometry.get(geometry_name)
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            placed = geometry.copy()
            placed.apply_transform(transform)
            meshes.append(placed)
    return meshes


COLOR_PARTS_KEY = "pixie_color_parts"  # metadata: [(first face, part mesh)] of a joined scene


def _join_keeping_colour_sources(meshes: list) -> "trimesh.Trimesh":  # noqa: F821
    """One mesh with every part's triangles; each part's own visual (texture, colours) is kept
    in metadata so colours are looked up per part, not in a repacked texture atlas (trimesh's
    atlas packing of several textures does not preserve texel colours)."""
    import trimesh

    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    joined = trimesh.Trimesh(
        vertices=np.concatenate([np.asarray(m.vertices) for m in meshes]),
        faces=np.concatenate([np.asarray(m.faces) + off for m, off in zip(meshes, offsets)]),
        process=False,
    )
    face_starts = np.cumsum([0] + [len(m.faces) for m in meshes])[:-1]
    joined.metadata[COLOR_PARTS_KEY] = [(int(start), m) for start, m in zip(face_starts, meshes)]
    return joined


# ---------------------------------------------------------------------------------------- sampling
def _face_areas(mesh) -> np.ndarray:
    tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_surface(mesh, n: int, rng: np.random.Generator, areas: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted uniform samples: (face index (n,), barycentric weights (n,3), points (n,3) f64)."""
    faces = np.asarray(mesh.faces)
    tri = np.asarray(mesh.vertices, np.float64)[faces]
    cumulative = np.cumsum(_face_areas(mesh) if areas is None else areas)
    face = np.searchsorted(cumulative, rng.random(n) * cumulative[-1], side="right")
    face = np.minimum(face, len(faces) - 1)
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    bary = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)
    points = np.einsum("nk,nkd->nd", bary, tri[face])
    return face, bary, points


def surface_frames(mesh, face: np.ndarray) -> np.ndarray:
    """Rotation matrices (n,3,3) with columns (tangent, bitangent, unit normal) of each face."""
    tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)[face]]
    edge = tri[:, 1] - tri[:, 0]
    normal = np.cross(edge, tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    tangent = edge - np.sum(edge * normal, axis=1, keepdims=True) * normal
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    bitangent = np.cross(normal, tangent)
    return np.stack([tangent, bitangent, normal], axis=2)


# ---------------------------------------------------------------------------------------- colour
def surface_colors(mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Base colour (n,3) in [0,1] at surface samples: texture, vertex or face colours, else grey.

    A mesh joined from a scene's parts takes each sample's colour from its own part.
    """
    parts = getattr(mesh, "metadata", {}).get(COLOR_PARTS_KEY)
    if parts and sum(len(p.faces) for _, p in parts) == len(mesh.faces):
        colors = np.empty((len(face), 3), np.float32)
        for start, part in parts:
            sel = (face >= start) & (face < start + len(part.faces))
            if sel.any():
                colors[sel] = _own_surface_colors(part, face[sel] - start, bary[sel])
        return colors
    return _own_surface_colors(mesh, face, bary)


def _own_surface_colors(mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    n = len(face)
    if kind == "texture" or hasattr(visual, "material"):  # TextureVisuals, with or without UVs
        material = getattr(visual, "material", None)
        image, factor = _material_image_and_factor(material)
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            uv_at = np.einsum("nk,nkd->nd", bary, np.asarray(uv, np.float64)[np.asarray(mesh.faces)[face]])
            texel_rgb = bilinear_texture_lookup(image, uv_at) / 255.0
            return np.clip(texel_rgb * factor, 0.0, 1.0).astype(np.float32)
        return np.tile(np.clip(factor, 0.0, 1.0), (n, 1)).astype(np.float32)
    if kind == "vertex":
        colors = np.asarray(visual.vertex_colors, np.float64)[:, :3] / 255.0
        corner = colors[np.asarray(mesh.faces)[face]]
        return np.einsum("nk,nkd->nd", bary, corner).astype(np.float32)
    if kind == "face":
        return (np.asarray(visual.face_colors, np.float64)[face, :3] / 255.0).astype(np.float32)
    return np.full((n, 3), DEFAULT_GREY, np.float32)


def _material_image_and_factor(material) -> tuple[np.ndarray | None, np.ndarray]:
    """(texture as uint8 RGB (H,W,3) or None, colour factor (3,) in [0,1]) of a trimesh material.

    glTF (PBR) materials: baseColorTexture × baseColorFactor. Simple (OBJ) materials: the diffuse
    image alone when there is one (as viewers show it), else the diffuse colour.
    """
    image, factor = None, np.ones(3)
    if material is None:
        return None, np.full(3, DEFAULT_GREY)
    if hasattr(material, "baseColorTexture"):
        image = material.baseColorTexture
        if material.baseColorFactor is not None:
            raw = np.asarray(material.baseColorFactor)
            factor = raw[:3].astype(np.float64) / (255.0 if np.issubdtype(raw.dtype, np.integer) else 1.0)
    else:
        image = getattr(material, "image", None)
        if image is None and getattr(material, "diffuse", None) is not None:
            factor = np.asarray(material.diffuse, np.float64)[:3] / 255.0
    if image is None:
        return None, factor
    return np.asarray(image.convert("RGB"), np.uint8), factor  # uint8 keeps 4k textures small


def bilinear_texture_lookup(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinearly interpolated colours (n,C) float64 of `image` (H,W,C), in the image's own value
    scale, at `uv` (n,2), with repeat wrapping (glTF's default sampler).

    UV follows trimesh's convention (origin at the image's bottom-left, v up); texel (i, j) has
    its centre at u = (j + 0.5)/W, v = 1 − (i + 0.5)/H.
    """
    h, w = image.shape[:2]
    x = np.asarray(uv[:, 0], np.float64) * w - 0.5
    y = (1.0 - np.asarray(uv[:, 1], np.float64)) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    x0, y0 = x0 % w, y0 % h
    def texel(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return image[rows, cols].astype(np.float64)

    top = texel(y0, x0) * (1 - fx) + texel(y0, x1) * fx
    bottom = texel(y1, x0) * (1 - fx) + texel(y1, x1) * fx
    return top * (1 - fy) + bottom * fy


# ---------------------------------------------------------------------------------------- interior
class InsideTest:
    """Which points lie inside a closed mesh: parity of the crossings of an upward (+z) ray.

    Vectorised: triangles are bucketed once into an xy grid by their projected bounding boxes,
    so each point is tested only against the triangles over its own grid cell.
    """

    MAX_BUCKET_ENTRIES = 8_000_000  # (triangle, cell) pairs; the grid coarsens to stay below

    def __init__(self, mesh, cells_per_side: int | None = None) -> None:
        tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)]
        a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        keep = np.abs(area2) > 1e-18  # triangles seen edge-on from +z never cross a vertical ray
        self.tri, self.area2 = tri[keep], area2[keep]
        if len(self.tri) == 0:
            return
        xy = self.tri[:, :, :2]
        self.lo = xy.reshape(-1, 2).min(axis=0)
        self.span = np.maximum(xy.reshape(-1, 2).max(axis=0) - self.lo, 1e-12)
        g = cells_per_side or int(np.clip(2 * np.sqrt(len(self.tri)), 1, 1024))
        while True:
            self.g = g
            tmin, tmax = self._cell(xy.min(axis=1)), self._cell(xy.max(axis=1))
            nx, ny = tmax[:, 0] - tmin[:, 0] + 1, tmax[:, 1] - tmin[:, 1] + 1
            counts = nx * ny
            if counts.sum() <= max(self.MAX_BUCKET_ENTRIES, 4 * len(self.tri)) or g == 1:
                break
            g = max(1, g // 2)
        tri_id = np.repeat(np.arange(len(self.tri)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        bucket = (tmin[tri_id, 0] + local % nx[tri_id]) * g + tmin[tri_id, 1] + local // nx[tri_id]
        order = np.argsort(bucket, kind="stable")
        self.bucket_tris = tri_id[order]
        self.starts = np.searchsorted(bucket[order], np.arange(g * g), side="left")
        self.ends = np.searchsorted(bucket[order], np.arange(g * g), side="right")

    def _cell(self, xy: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((xy - self.lo) / self.span * self.g).astype(np.int64), 0, self.g - 1)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Boolean (n,): True where a point (n,3) lies inside the mesh."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if len(self.tri) == 0 or len(points) == 0:
            return np.zeros(len(points), bool)
        in_footprint = np.all((points[:, :2] >= self.lo) & (points[:, :2] <= self.lo + self.span), axis=1)
        cell = self._cell(points[:, :2])
        bucket = cell[:, 0] * self.g + cell[:, 1]
        per_point = np.where(in_footprint, self.ends[bucket] - self.starts[bucket], 0)
        crossings = np.zeros(len(points), np.int64)
        for first in range(0, len(points), 50_000):  # bounded memory for (point, triangle) pairs
            ids = np.arange(first, min(first + 50_000, len(points)))
            cnt = per_point[ids]
            if cnt.sum() == 0:
                continue
            pid = np.repeat(ids, cnt)
            offset = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            tid = self.bucket_tris[self.starts[bucket[pid]] + offset]
            hits = pid[_ray_hits(points[pid], self.tri[tid], self.area2[tid])]
            crossings += np.bincount(hits, minlength=len(points))
        return crossings % 2 == 1


def points_inside(mesh, points: np.ndarray) -> np.ndarray:
    """Boolean (n,): which points (n,3) lie inside the closed mesh."""
    return InsideTest(mesh)(points)


def _ray_hits(p: np.ndarray, tri: np.ndarray, area2: np.ndarray) -> np.ndarray:
    """Whether the upward ray from each p crosses the paired triangle (half-open edge rule)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]

    def edge(u, v):
        return (v[:, 0] - u[:, 0]) * (p[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[:, 0] - u[:, 0])

    sign = np.sign(area2)
    w0, w1, w2 = edge(b, c) * sign, edge(c, a) * sign, edge(a, b) * sign
    inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0) & ((w0 > 0) | (w1 > 0) | (w2 > 0))
    total = np.abs(area2)
    z = (w0 * a[:, 2] + w1 * b[:, 2] + w2 * c[:, 2]) / total
    return inside & (z > p[:, 2])


def is_closed(mesh) -> bool:
    """Whether the mesh's surface is watertight once coincident vertices are merged.

    Files such as STL (and UV seams) repeat vertices per face; topology is judged on positions only.
    """
    import trimesh

    if mesh.is_watertight:
        return True
    geometric = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=True)
    return bool(geometric.is_watertight)


def sample_interior(mesh, n: int, rng: np.random.Generator, batch_size: int = 200_000) -> np.ndarray:
    """`n` uniform random points (n,3) inside a watertight mesh (rejection from its bounding box)."""
    lo, hi = np.asarray(mesh.bounds[0], np.float64), np.asarray(mesh.bounds[1], np.float64)
    fraction = float(np.clip(abs(mesh.volume) / np.prod(np.maximum(hi - lo, 1e-12)), 0.01, 1.0))
    inside = InsideTest(mesh)
    expected_batches = max(1, int(np.ceil(n / fraction * 1.1 / batch_size)))
    found: list[np.ndarray] = []
    total = 0
    for _ in progress(range(max(100, 3 * expected_batches)), desc="filling interior",
                            total=expected_batches, unit="batch"):
        batch = int(min(max((n - total) / fraction * 1.1, 256), batch_size))
        candidates = lo + rng.random((batch, 3)) * (hi - lo)
        accepted = candidates[inside(candidates)]
        found.append(accepted)
        total += len(accepted)
        if total >= n:
            break
    points = np.concatenate(found)[:n]
    if len(points) < n:
        raise InputError(f"could only place {len(points)} of {n} interior Gaussians (is the mesh closed?)",
                         mesh.metadata.get("source"))
    return points


def nearest_surface_sample(tree, inner: np.ndarray, spacing: float) -> np.ndarray:
    """Index of the surface sample nearest each interior point: exact within 4 sample spacings of
    the surface; deeper inside, a sample at most twice as far as the nearest (an exact search is
    very slow there, e.g. at a sphere's centre every surface sample is almost equally near)."""
    distance, index = tree.query(inner, distance_upper_bound=4.0 * spacing)
    deep = ~np.isfinite(distance)
    if deep.any():
        index[deep] = tree.query(inner[deep], eps=1.0)[1]
    return index


# ---------------------------------------------------------------------------------------- splat
CONVERT_BYTES_PER_GAUSSIAN = 400  # peak working memory per Gaussian (samples, attributes, table)


def mesh_to_splat(mesh, n_surface: int, rng: np.random.Generator, *, fill: bool = False,
                  n_fill: int | None = None, rgb: np.ndarray | None = None, color_noise: float = 0.0,
                  normal_scale_ratio: float = 0.1, opacity: float = 0.9) -> SplatCloud:
    """A degree-0 SplatCloud sampled from `mesh` (lengths in the mesh's unit).

    n_surface: surface Gaussians (area-weighted). fill: add `n_fill` (default n_surface)
    isotropic interior Gaussians; the mesh must be watertight. rgb: one fixed colour (3,) in
    [0,1] instead of the mesh's own. color_noise: std-dev of per-Gaussian rgb jitter.
    normal_scale_ratio: normal std-dev / tangential std-dev. opacity: α in (0,1).
    Normals are written as `nx ny nz` (surface normal; zero for interior Gaussians).
    """
    source = mesh.metadata.get("source") if hasattr(mesh, "metadata") else None
    if n_surface < 1:
        raise InputError(f"surface Gaussian count must be ≥ 1 (got {n_surface})", source)
    if not 0.0 < opacity < 1.0:
        raise InputError(f"opacity must lie in (0, 1) (got {opacity})", source)
    from .limits import require_memory

    total = n_surface + ((n_fill if n_fill is not None else n_surface) if fill else 0)
    require_memory(total * CONVERT_BYTES_PER_GAUSSIAN, f"converting to {total} Gaussians", source)
    areas = _face_areas(mesh)
    total_area = float(areas.sum())
    if not total_area > 0:
        raise InputError("mesh has zero surface area", source)

    face, bary, points = sample_surface(mesh, n_surface, rng, areas)
    # frames and quaternions per face (then indexed) when faces are fewer than samples
    used, which = (np.unique(face, return_inverse=True) if n_surface > len(mesh.faces)
                   else (face, np.arange(n_surface)))
    face_frames = surface_frames(mesh, used)
    frames = face_frames[which]
    colors = surface_colors(mesh, face, bary) if rgb is None else np.tile(
        np.asarray(rgb, np.float32).reshape(1, 3), (n_surface, 1))
    tangent_std = TANGENT_SCALE_RATIO * np.sqrt(total_area / n_surface)
    surface_scales = np.array([tangent_std, tangent_std, tangent_std * normal_scale_ratio])
    means = [points]
    log_scales = [np.tile(np.log(surface_scales), (n_surface, 1))]
    quats = [rotmat_to_quat(face_frames)[which]]
    normals = [frames[:, :, 2]]
    all_colors = [colors]

    if fill:
        if not is_closed(mesh):
            raise InputError("--fill needs a watertight (closed) mesh; this one has holes", source)
        count = n_surface if n_fill is None else int(n_fill)
        if count > 0:
            from scipy.spatial import cKDTree

            inner = sample_interior(mesh, count, rng)
            nearest = nearest_surface_sample(cKDTree(points), inner, np.sqrt(total_area / n_surface))
            inner_std = FILL_SCALE_RATIO * (abs(float(mesh.volume)) / count) ** (1.0 / 3.0)
            means.append(inner)
            log_scales.append(np.full((count, 3), np.log(inner_std)))
            quats.append(np.tile([1.0, 0.0, 0.0, 0.0], (count, 1)))
            normals.append(np.zeros((count, 3)))
            all_colors.append(colors[nearest])

    rgb_all = np.concatenate(all_colors).astype(np.float64)
    if color_noise > 0:
        rgb_all = rgb_all + rng.normal(0.0, color_noise, rgb_all.shape)
    rgb_all = np.clip(rgb_all, 0.0, 1.0)
    n_total = len(rgb_all)
    cloud = SplatCloud.from_arrays(
        means=np.concatenate(means),
        log_scales=np.concatenate(log_scales),
        rotations=np.concatenate(quats),
        opacity_logits=np.full(n_total, np.log(opacity / (1.0 - opacity))),
        sh_dc=rgb_to_sh_dc(rgb_all),
    )
    normal_all = np.concatenate(normals).astype(np.float32)
    for axis, name in enumerate(("nx", "ny", "nz")):
        cloud.extras[name] = np.ascontiguousarray(normal_all[:, axis])
    order = cloud.property_order
    cloud.property_order = order[:3] + ["nx", "ny", "nz"] + order[3:]
    cloud.source = source
    return cloud
