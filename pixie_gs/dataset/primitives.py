"""Small mesh builders (numpy + trimesh only, no optional trimesh extras) used by the recipes.

All lengths are metres, z is up. Closed builders (lathe with caps, ellipsoid, box, pile slab)
return watertight meshes so that they can be filled with interior Gaussians.
"""
from __future__ import annotations

import numpy as np
import trimesh


def lathe(radii: np.ndarray, heights: np.ndarray, sections: int = 24, cap_bottom: bool = True,
          cap_top: bool = True) -> trimesh.Trimesh:
    """Surface of revolution about z of the profile (radius_i, height_i), i from bottom to top.

    Caps close the bottom/top ring with a centre vertex (watertight when both are on and every
    radius is > 0).
    """
    r = np.asarray(radii, np.float64)
    h = np.asarray(heights, np.float64)
    k = len(r)
    theta = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    verts = np.concatenate([np.column_stack([ring * r[i], np.full(sections, h[i])]) for i in range(k)])
    faces = []
    j = np.arange(sections)
    jn = (j + 1) % sections
    for i in range(k - 1):
        a, b = i * sections + j, i * sections + jn
        c, d = (i + 1) * sections + jn, (i + 1) * sections + j
        faces.append(np.column_stack([a, b, c]))
        faces.append(np.column_stack([a, c, d]))
    extra = []
    if cap_bottom:
        centre = len(verts) + len(extra)
        extra.append([0.0, 0.0, h[0]])
        faces.append(np.column_stack([np.full(sections, centre), jn, j]))
    if cap_top:
        centre = len(verts) + len(extra)
        extra.append([0.0, 0.0, h[-1]])
        top = (k - 1) * sections
        faces.append(np.column_stack([np.full(sections, centre), top + j, top + jn]))
    if extra:
        verts = np.concatenate([verts, np.asarray(extra)])
    return trimesh.Trimesh(vertices=verts, faces=np.concatenate(faces), process=False)


def frame_along(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """4×4 transform taking the z axis segment [0, |p1−p0|] onto the segment p0 → p1."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    z = axis / max(length, 1e-12)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, p0
    return T


def tapered_segment(p0: np.ndarray, p1: np.ndarray, r0: float, r1: float,
                    sections: int = 8) -> trimesh.Trimesh:
    """Closed tapered cylinder (branch, stem) from p0 (radius r0) to p1 (radius r1)."""
    length = float(np.linalg.norm(np.asarray(p1, float) - np.asarray(p0, float)))
    mesh = lathe(np.array([r0, r1]), np.array([0.0, length]), sections=sections)
    mesh.apply_transform(frame_along(p0, p1))
    return mesh


def ellipsoid(centre: np.ndarray, radii: np.ndarray, subdivisions: int = 1,
              rotation: np.ndarray | None = None) -> trimesh.Trimesh:
    """Closed ellipsoid with semi-axes `radii` (m), optionally rotated by a 3×3 matrix."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = mesh.vertices * np.asarray(radii, float)
    if rotation is not None:
        v = v @ np.asarray(rotation, float).T
    return trimesh.Trimesh(vertices=v + np.asarray(centre, float), faces=mesh.faces.copy(), process=False)


def box(extents: np.ndarray, centre: np.ndarray) -> trimesh.Trimesh:
    """Closed axis-aligned box with side lengths `extents` (m) centred at `centre`."""
    T = np.eye(4)
    T[:3, 3] = centre
    return trimesh.creation.box(extents=np.asarray(extents, float), transform=T)


def blade(base: np.ndarray, height: float, width: float, lean: np.ndarray, segments: int = 5) -> trimesh.Trimesh:
    """Open, tapered, bending strip (a grass blade or leaf): width → 0 at the tip.

    `lean` (2,) is the horizontal tip displacement per metre of height squared (bending).
    """
    base = np.asarray(base, float)
    lean = np.asarray(lean, float)
    t = np.linspace(0.0, 1.0, segments + 1)
    centre = np.column_stack([base[0] + lean[0] * (t * height) ** 2 / max(height, 1e-9),
                              base[1] + lean[1] * (t * height) ** 2 / max(height, 1e-9),
                              base[2] + t * height])
    d = np.array([-lean[1], lean[0]])
    d = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-12 else np.array([1.0, 0.0])
    half = 0.5 * width * (1.0 - t) ** 0.8
    side = np.column_stack([d[0] * half, d[1] * half, np.zeros_like(t)])
    verts = np.concatenate([centre - side, centre + side])
    n = segments + 1
    faces = []
    for i in range(segments):
        a, b, c, e = i, i + 1, n + i + 1, n + i
        faces += [[a, b, c], [a, c, e]]
    return trimesh.Trimesh(vertices=verts, faces=np.asarray(faces), process=False)


def leaf_sheet(base: np.ndarray, along: np.ndarray, normal: np.ndarray, length: float, width: float,
               cup: float = 0.0, segments: int = 8, columns: int = 6) -> trimesh.Trimesh:
    """Open sheet shaped like a broad leaf: from `base` along `along` for `length` (m), widest (`width`) near its
    middle and pointed at both ends, its face turned to `normal` (made orthogonal to `along`), cupped by `cup`
    (the edges rise by cup × width toward the normal)."""
    a = np.asarray(along, float)
    a = a / np.linalg.norm(a)
    n = np.asarray(normal, float) - np.dot(normal, a) * a
    n = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else frame_along(np.zeros(3), a)[:3, 0]
    side = np.cross(n, a)
    u = np.linspace(0.0, 1.0, segments + 1)[:, None]
    v = np.linspace(-1.0, 1.0, columns + 1)[None, :]
    half = 0.5 * width * np.sin(np.pi * u) ** 0.7
    lift = cup * width * v ** 2
    verts = (np.asarray(base, float)[None, None, :] + (u * length)[..., None] * a + (v * half)[..., None] * side
             + lift[..., None] * n).reshape(-1, 3)
    faces = []
    for i in range(segments):
        for j in range(columns):
            k = i * (columns + 1) + j
            faces += [[k, k + columns + 1, k + columns + 2], [k, k + columns + 2, k + 1]]
    return trimesh.Trimesh(vertices=verts, faces=np.asarray(faces), process=False)


def pile_slab(radius: float, lower, upper, rings: int = 14, sections: int = 36) -> trimesh.Trimesh:
    """Closed solid between two height fields over a disc of `radius` (m).

    `lower(r, theta)` and `upper(r, theta)` give heights (m); the solid is closed at the centre
    by single vertices and at the rim by a vertical side band (upper is clamped ≥ lower + 1 mm).
    """
    rs = radius * np.linspace(0.0, 1.0, rings + 1)[1:]
    theta = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    R, TH = np.meshgrid(rs, theta, indexing="ij")  # (rings, sections)
    zl = np.asarray(lower(R, TH), float)
    zu = np.maximum(np.asarray(upper(R, TH), float), zl + 1e-3)
    zl0 = float(np.asarray(lower(np.zeros(1), np.zeros(1)), float).reshape(-1)[0])
    zu0 = max(float(np.asarray(upper(np.zeros(1), np.zeros(1)), float).reshape(-1)[0]), zl0 + 1e-3)
    xy = np.stack([R * np.cos(TH), R * np.sin(TH)], axis=-1).reshape(-1, 2)
    top = np.column_stack([xy, zu.reshape(-1)])
    bottom = np.column_stack([xy, zl.reshape(-1)])
    n = len(top)
    verts = np.concatenate([top, bottom, [[0.0, 0.0, zu0], [0.0, 0.0, zl0]]])
    ct, cb = 2 * n, 2 * n + 1
    j = np.arange(sections)
    jn = (j + 1) % sections
    faces = [np.column_stack([np.full(sections, ct), j, jn]),            # top centre fan (up)
             np.column_stack([np.full(sections, cb), n + jn, n + j])]    # bottom centre fan (down)
    for i in range(rings - 1):
        a, b = i * sections + j, i * sections + jn
        c, d = (i + 1) * sections + jn, (i + 1) * sections + j
        faces += [np.column_stack([a, d, c]), np.column_stack([a, c, b])]
        faces += [np.column_stack([n + a, n + c, n + d]), np.column_stack([n + a, n + b, n + c])]
    o = (rings - 1) * sections
    faces += [np.column_stack([o + j, n + o + j, n + o + jn]), np.column_stack([o + j, n + o + jn, o + jn])]
    mesh = trimesh.Trimesh(vertices=verts, faces=np.concatenate(faces), process=False)
    return mesh


def concatenate(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """One mesh holding all of `meshes` (no merging of vertices; each stays closed if it was)."""
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(np.asarray(m.vertices, float))
        faces.append(np.asarray(m.faces) + offset)
        offset += len(m.vertices)
    return trimesh.Trimesh(vertices=np.concatenate(verts), faces=np.concatenate(faces), process=False)


def rotation_z(angle_rad: float) -> np.ndarray:
    """3×3 rotation about z (yaw)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def random_rotation(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Uniform random 3×3 rotation (QR of a Gaussian matrix, sign-fixed); `n` of them, (n,3,3), when given."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3) if n is None else (n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=-2, axis2=-1))[..., None, :]
    q[..., :, 0] *= np.where(np.linalg.det(q) < 0, -1.0, 1.0)[..., None]
    return q
