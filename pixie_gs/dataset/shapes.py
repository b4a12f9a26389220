"""Geometry recipes: one function per object kind, building part-labelled meshes (metres, z up).

A recipe takes an RNG and the set of its part names the object has, and returns `Piece`s (a mesh,
the part it belongs to, a base colour, colour noise, and whether to fill its interior) plus the
shape parameters it drew (stored in the object's index). Recipes are registered by name in
`RECIPES`; classes.json refers to them by that name. Objects stand on z = 0, centred on x = y = 0.
Hollow things (cans, crates, balls, pots, vases) are shells; piles, soil and toys are filled.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

from .primitives import (blade, box, concatenate, ellipsoid, lathe, leaf_sheet, pile_slab, random_rotation,
                         tapered_segment)


@dataclass
class Piece:
    """A mesh belonging to one part, with its colour (RGB in [0, 1]) and how to sample it."""

    part: str
    mesh: trimesh.Trimesh
    rgb: tuple[float, float, float]
    color_noise: float = 0.04
    fill: bool = False
    weight: float = 1.0  # multiplies the share of Gaussians this piece gets (per m² of surface)


Recipe = Callable[[np.random.Generator, set], tuple[list[Piece], dict]]
RECIPES: dict[str, Recipe] = {}


def recipe(name: str) -> Callable[[Recipe], Recipe]:
    def register(fn: Recipe) -> Recipe:
        RECIPES[name] = fn
        return fn
    return register


# ---------------------------------------------------------------------------------- colours
def jitter(rng: np.random.Generator, rgb, amount: float = 0.06) -> tuple[float, float, float]:
    """Base colour varied per object: a brightness factor plus a small per-channel tint (the tint
    is a quarter of `amount`, so a colour keeps its hue: bark stays brown, leaves green)."""
    c = np.asarray(rgb, float) * rng.uniform(1 - amount, 1 + amount) + rng.normal(0.0, amount / 4, 3)
    return tuple(float(v) for v in np.clip(c, 0.0, 1.0))


def pick(rng: np.random.Generator, options: list):
    return options[int(rng.integers(len(options)))]


def side_stream(rng: np.random.Generator, salt: int) -> np.random.Generator:
    """A generator seeded from `rng`'s present state without advancing it (PCG64). Shape options added
    to a recipe later draw from here, so an object drawn before them (the shipped examples) keeps
    every draw of the main stream and, where the option is off, its exact shape."""
    state = int(rng.bit_generator.state["state"]["state"])
    return np.random.default_rng([state & (2**64 - 1), state >> 64, salt])


BARK = [(0.36, 0.25, 0.17), (0.30, 0.22, 0.15), (0.45, 0.35, 0.25), (0.40, 0.30, 0.22)]
LEAF_GREENS = [(0.20, 0.45, 0.15), (0.28, 0.52, 0.18), (0.15, 0.35, 0.12), (0.35, 0.55, 0.20),
               (0.22, 0.40, 0.20)]
AUTUMN = [(0.80, 0.45, 0.12), (0.75, 0.25, 0.10), (0.85, 0.65, 0.15)]
POTS = [(0.72, 0.40, 0.25), (0.65, 0.35, 0.22), (0.30, 0.30, 0.32), (0.90, 0.90, 0.88), (0.25, 0.35, 0.55)]
SOIL = [(0.30, 0.21, 0.14), (0.38, 0.27, 0.17), (0.24, 0.18, 0.12)]
PETALS = [(0.90, 0.15, 0.20), (0.95, 0.55, 0.70), (0.98, 0.85, 0.20), (0.97, 0.97, 0.95), (0.60, 0.30, 0.75),
          (0.98, 0.55, 0.15)]
VASES = [(0.92, 0.92, 0.90), (0.20, 0.35, 0.65), (0.70, 0.40, 0.25), (0.15, 0.15, 0.18), (0.55, 0.75, 0.70),
         (0.80, 0.70, 0.50)]
TOY_COLOURS = [(0.98, 0.85, 0.10), (0.95, 0.30, 0.30), (0.25, 0.50, 0.90), (0.30, 0.75, 0.35),
               (0.95, 0.55, 0.75), (0.60, 0.40, 0.25)]
CAN_PAINT = [(0.80, 0.05, 0.08), (0.10, 0.20, 0.60), (0.10, 0.50, 0.20), (0.95, 0.75, 0.10), (0.10, 0.10, 0.10),
             (0.85, 0.85, 0.88), (0.55, 0.10, 0.45), (0.95, 0.45, 0.05)]
ALUMINIUM = (0.78, 0.79, 0.82)
CRATE_METAL = [(0.55, 0.57, 0.60), (0.70, 0.72, 0.74), (0.42, 0.44, 0.47), (0.25, 0.35, 0.22),
               (0.20, 0.30, 0.55), (0.65, 0.15, 0.12)]
SAND = [(0.82, 0.70, 0.48), (0.76, 0.62, 0.40), (0.88, 0.78, 0.58), (0.72, 0.50, 0.32)]
SNOW = [(0.93, 0.94, 0.97), (0.85, 0.87, 0.90), (0.80, 0.82, 0.86)]
MUD = [(0.33, 0.24, 0.16), (0.28, 0.22, 0.17), (0.40, 0.30, 0.20)]


def _round(params: dict) -> dict:
    """JSON-ready shape parameters: floats rounded to 4 significant digits."""
    out = {}
    for k, v in params.items():
        if isinstance(v, (float, np.floating)):
            out[k] = float(f"{float(v):.4g}")
        elif isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            out[k] = int(v)
        else:
            out[k] = v
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(np.linalg.norm(v), 1e-12)


def _upward_direction(rng: np.random.Generator, parent: np.ndarray, spread: float) -> np.ndarray:
    """A direction near `parent`, tilted by up to `spread` rad, never pointing down much."""
    d = _unit(parent + rng.normal(0.0, spread, 3))
    d[2] = max(d[2], 0.15)
    return _unit(d)


def grow_branches(rng: np.random.Generator, start: np.ndarray, direction: np.ndarray, length: float,
                  radius: float, depth: int, children: tuple[int, int], spread: float,
                  sections: int = 7) -> tuple[list[trimesh.Trimesh], list[np.ndarray], list[float]]:
    """Recursive branching: segments, tip positions and tip radii (m) of a branch system."""
    end = start + direction * length
    segs = [tapered_segment(start, end, radius, radius * 0.7, sections)]
    if depth == 0:
        return segs, [end], [radius * 0.7]
    tips, tip_r = [], []
    for _ in range(int(rng.integers(children[0], children[1] + 1))):
        s, t, r = grow_branches(rng, end, _upward_direction(rng, direction, spread),
                                length * rng.uniform(0.55, 0.8), radius * 0.6, depth - 1, children, spread,
                                sections)
        segs += s
        tips += t
        tip_r += r
    return segs, tips, tip_r


def blob_cluster(rng: np.random.Generator, centre: np.ndarray, size: float, count: int,
                 flatten: float = 0.8) -> list[trimesh.Trimesh]:
    """`count` overlapping ellipsoids around `centre` (foliage clumps), each ~`size` m across."""
    blobs = []
    for _ in range(count):
        c = centre + rng.normal(0.0, size * 0.45, 3) * np.array([1.0, 1.0, flatten])
        radii = size * rng.uniform(0.35, 0.6) * np.array([1.0, rng.uniform(0.7, 1.0), rng.uniform(0.6, 0.9)])
        blobs.append(ellipsoid(c, radii, 1, random_rotation(rng)))
    return blobs


# ---------------------------------------------------------------------------------- plants
LEAFY_HOUSEPLANT_SHARE = 0.3  # potted broadleaf trees drawn as house plants with broad flat leaves


def leaf_spray(rng: np.random.Generator, fork: np.ndarray, tips: list[np.ndarray], size: float
               ) -> list[trimesh.Trimesh]:
    """Broad flat leaves (a jade plant's, a rubber plant's) along each branch line from `fork` to its tip and
    at the tip: 2–4 per branch, from the fork on, each `size` × 0.5–1 long, half to four fifths as wide, turned outward and
    tilted toward the light, slightly cupped. Real potted plants show such leaves, not the clumps of
    `blob_cluster`, and captures of them read as stiff as boards."""
    leaves = []
    for tip in tips:
        branch = tip - fork
        for u in np.append(rng.uniform(0.0, 0.9, int(rng.integers(1, 4))), 1.0):
            at = fork + u * branch
            out = np.append(rng.normal(0.0, 1.0, 2), rng.uniform(-0.2, 0.8))
            along = _unit(out + 0.5 * _unit(branch))
            normal = _unit(np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.5, 3))
            length = size * rng.uniform(0.5, 1.0)
            leaves.append(leaf_sheet(at, along, normal, length, length * rng.uniform(0.5, 0.8),
                                     cup=rng.uniform(0.0, 0.25)))
    return leaves


def pot_pieces(rng: np.random.Generator, height: float, radius: float, part: str,
               side: np.random.Generator | None = None) -> tuple[list[Piece], float, str]:
    """A flower pot shell with a soil disc inside; returns pieces, top height (m) and the pot's shape
    ("tapered" or "bowl"). The shell is tapered with a rim lip, or (a third of the pots, when a `side`
    stream is given) a round-bellied bowl."""
    taper = rng.uniform(0.65, 0.9)
    lip = rng.uniform(1.03, 1.1)
    radii = np.array([radius * taper, radius, radius * lip, radius * lip])
    heights = np.array([0.0, height * 0.85, height * 0.87, height])
    bowl = side is not None and side.random() < 0.33
    if bowl:
        t = np.linspace(0.0, 1.0, 8)
        radii = radius * (taper * 0.8 + (1.0 - taper * 0.8) * np.sin(np.pi * np.clip(0.15 + 0.75 * t, 0, 1)) ** 0.5)
        heights = t * height
    shell = lathe(radii, heights, sections=28, cap_bottom=True, cap_top=False)
    soil_z = height * rng.uniform(0.85, 0.95)
    soil_r = radii[-1] * 0.95 if bowl else radius * 0.98
    soil = lathe(np.array([soil_r, soil_r]), np.array([soil_z - 0.005, soil_z]), 28)
    pieces = [Piece(part, shell, jitter(rng, pick(rng, POTS)), 0.03),
              Piece(part, soil, jitter(rng, pick(rng, SOIL)), 0.05, weight=0.6)]
    return pieces, soil_z, "bowl" if bowl else "tapered"


@recipe("potted_tree")
def potted_tree(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Tree of height 1–2.5 m: optional pot, trunk with recursive branches, leaf clusters or
    conifer tiers. A quarter of the potted broadleaf ones are house plants: a short trunk and foliage
    along the branches down to the pot (a real potted plant hid its stem; its pot read as trunk wood)."""
    side = side_stream(rng, 1)
    height = rng.uniform(1.0, 2.5)
    pieces: list[Piece] = []
    base_z = 0.0
    has_pot = "pot" in parts
    if has_pot:
        pot_h = height * rng.uniform(0.14, 0.22)
        pot_pcs, base_z, pot_shape = pot_pieces(rng, pot_h, pot_h * rng.uniform(0.7, 1.0), "pot", side)
        pieces += pot_pcs
    kind = "conifer" if rng.random() < 0.3 else "broadleaf"
    bark = jitter(rng, pick(rng, BARK))
    leaf = jitter(rng, pick(rng, AUTUMN if (kind == "broadleaf" and rng.random() < 0.12) else LEAF_GREENS))
    trunk_r = height * rng.uniform(0.018, 0.035)
    top = height  # the tree (with its pot) is `height` tall
    if kind == "conifer":
        trunk_top = np.array([0.0, 0.0, top])
        trunk = [tapered_segment(np.array([0.0, 0.0, base_z - 0.02]), trunk_top, trunk_r, trunk_r * 0.3, 10)]
        tiers = int(rng.integers(3, 6))
        crown_base = base_z + (top - base_z) * rng.uniform(0.2, 0.35)
        width = (top - base_z) * rng.uniform(0.22, 0.35)
        leaves = []
        span = top - crown_base
        for k in range(tiers):
            z0 = crown_base + span * k / tiers * 0.85
            r = width * (1.0 - 0.75 * k / tiers)
            leaves.append(lathe(np.array([r, r * 0.15]), np.array([z0, z0 + span * 1.6 / tiers]), 24))
        pieces += [Piece("trunk", concatenate(trunk), bark, 0.05),
                   Piece("leaves", concatenate(leaves), leaf, 0.07)]
        params = {"height_m": height, "kind": kind, "tiers": tiers, "crown_radius_m": width}
    else:
        trunk_len = (top - base_z) * rng.uniform(0.35, 0.55)
        houseplant = has_pot and side.random() < 0.25
        leafy_rng = side_stream(rng, 2)  # broad flat leaves (since stop 43): its own stream, so others stay
        leafy = has_pot and leafy_rng.random() < LEAFY_HOUSEPLANT_SHARE
        if leafy:
            houseplant = True
            bark = jitter(leafy_rng, pick(leafy_rng, LEAF_GREENS), 0.1) if leafy_rng.random() < 0.6 else bark
            bark = tuple(0.75 * c for c in bark) if leafy_rng.random() < 0.5 else bark
        if houseplant:
            trunk_len = (top - base_z) * side.uniform(0.06, 0.18)
        direction = _unit(np.array([rng.normal(0, 0.08), rng.normal(0, 0.08), 1.0]))
        start = np.array([0.0, 0.0, base_z - 0.02])
        segs = [tapered_segment(start, start + direction * trunk_len, trunk_r, trunk_r * 0.8, 10)]
        fork = start + direction * trunk_len
        depth = int(rng.integers(1, 3))
        tips: list[np.ndarray] = []
        for _ in range(int(rng.integers(3, 6))):
            s, t, _r = grow_branches(rng, fork, _upward_direction(rng, np.array([0.0, 0.0, 1.0]), 0.7),
                                     (top - fork[2]) * rng.uniform(0.35, 0.5), trunk_r * 0.65, depth, (2, 3), 0.6)
            segs += s
            tips += t
        crown = (top - base_z) * rng.uniform(0.16, 0.24)
        if leafy:
            blobs = leaf_spray(leafy_rng, fork, tips, crown)
        else:
            blobs = []
            for tip in tips:
                blobs += blob_cluster(rng, tip, crown, int(rng.integers(3, 6)))
            if houseplant:  # foliage along each branch line from the fork to its tip
                for tip in tips:
                    for u in side.uniform(0.1, 0.8, 2):
                        blobs += blob_cluster(side, fork + u * (tip - fork), crown * 0.9, 3)
        pieces += [Piece("trunk", concatenate(segs), bark, 0.05),
                   Piece("leaves", concatenate(blobs), leaf, 0.08)]
        params = {"height_m": height, "kind": kind, "branch_depth": depth, "tips": len(tips),
                  "cluster_size_m": crown, "houseplant": houseplant}
        if leafy:
            params["broad_leaves"] = len(blobs)
    params["pot"] = has_pot
    if has_pot:
        params["pot_shape"] = pot_shape
    return pieces, _round(params)


@recipe("flowers_in_vase")
def flowers_in_vase(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Vase (shell of revolution: bulb, neck, lip) with 3–12 stems carrying petalled blossoms."""
    vh = rng.uniform(0.15, 0.35)
    vr = vh * rng.uniform(0.25, 0.45)
    t = np.linspace(0.0, 1.0, 9)
    bulge = rng.uniform(0.0, 0.6)
    neck = rng.uniform(0.45, 0.9)
    radii = vr * (0.7 + bulge * np.sin(np.pi * np.clip(t * 1.3, 0, 1)) * (1 - t) + 0.3 * t * neck)
    radii[-1] *= rng.uniform(1.0, 1.25)
    vase = lathe(radii, t * vh, sections=28, cap_bottom=True, cap_top=False)
    pieces = [Piece("vase", vase, jitter(rng, pick(rng, VASES)), 0.03)]
    mouth_r = float(radii[-1]) * 0.7
    n = int(rng.integers(3, 13))
    stem_len = vh * rng.uniform(0.9, 1.8)
    stems, heads, centres, leaves = [], [], [], []
    petal_rgb = jitter(rng, pick(rng, PETALS))
    mixed = rng.random() < 0.35
    head_pieces: list[Piece] = []
    for i in range(n):
        a = rng.uniform(0, 2 * np.pi)
        start = np.array([mouth_r * 0.5 * np.cos(a), mouth_r * 0.5 * np.sin(a), vh * 0.7])
        d = _unit(np.array([np.cos(a) * rng.uniform(0.1, 0.6), np.sin(a) * rng.uniform(0.1, 0.6), 1.0]))
        length = stem_len * rng.uniform(0.75, 1.15)
        end = start + d * length
        stems.append(tapered_segment(start, end, 0.003, 0.0025, 6))
        if rng.random() < 0.6:
            leaves.append(blade(start + d * length * 0.4, length * 0.35, 0.015,
                                rng.normal(0, 0.25, 2)))
        head_r = rng.uniform(0.02, 0.045)
        petals = []
        k = int(rng.integers(5, 9))
        for j in range(k):
            ang = 2 * np.pi * j / k
            off = np.array([np.cos(ang), np.sin(ang), 0.15]) * head_r * 0.8
            rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
            petals.append(ellipsoid(end + off, np.array([head_r * 0.75, head_r * 0.38, head_r * 0.12]), 1, rot))
        heads.append(concatenate(petals))
        centres.append(ellipsoid(end + np.array([0, 0, head_r * 0.1]), np.full(3, head_r * 0.3), 1))
        if mixed:
            head_pieces.append(Piece("flowers", heads[-1], jitter(rng, pick(rng, PETALS)), 0.05, weight=1.5))
    stem_rgb = jitter(rng, (0.25, 0.50, 0.18))
    pieces.append(Piece("flowers", concatenate(stems + leaves), stem_rgb, 0.05, weight=2.0))
    pieces += head_pieces if mixed else [Piece("flowers", concatenate(heads), petal_rgb, 0.05, weight=1.5)]
    pieces.append(Piece("flowers", concatenate(centres), jitter(rng, (0.85, 0.65, 0.10)), 0.05))
    return pieces, _round({"vase_height_m": vh, "vase_radius_m": vr, "stems": n, "stem_length_m": stem_len,
                           "mixed_colours": mixed})


BALANCE_ROUNDS = 3  # shrub: turn-and-replant rounds (the centre of mass stays within ~0.1° after three)


def surface_centroid(pieces: list[Piece]) -> np.ndarray:
    """Centroid (3,) of the pieces' surfaces weighted by area × piece weight: where the centroid of
    the object's Gaussians lands (assemble.allocate_counts shares them out by area × weight)."""
    total, moment = 0.0, np.zeros(3)
    for piece in pieces:
        tri = piece.mesh.triangles
        area = piece.mesh.area_faces * piece.weight
        total += float(area.sum())
        moment += (tri.mean(axis=1) * area[:, None]).sum(axis=0)
    return moment / max(total, 1e-30)


def balance_turn(pieces: list[Piece], foot: np.ndarray) -> np.ndarray:
    """4×4 turn about `foot` (3,), the centre of what the pieces stand on, that puts their centre
    of mass (surface_centroid) straight above it. Why: a thing with no fixed part (a free-standing
    bush) stays put only when its centre of mass is above its support."""
    lean = _unit(surface_centroid(pieces) - np.asarray(foot, float))
    axis = np.cross(lean, [0.0, 0.0, 1.0])
    if np.linalg.norm(axis) < 1e-9:
        return np.eye(4)
    return trimesh.transformations.rotation_matrix(float(np.arctan2(np.linalg.norm(axis), lean[2])), _unit(axis), foot)


def planted(start: np.ndarray, end: np.ndarray, z: float) -> np.ndarray:
    """The foot of a stem from `start` to `end` moved along the stem to height `z` (a stem that
    rises less than 1 in 5 keeps its foot)."""
    d = end - start
    if d[2] < 0.2 * np.linalg.norm(d):
        return start
    return start + d * ((z - start[2]) / d[2])


@recipe("shrub")
def shrub(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Free-standing bush 0.5–1.3 m: thick stems from the base, thin twigs, foliage clumps, turned
    about its base so it balances (balance_turn) and its stems planted again: a bush has no fixed part and its stems start
    within a few centimetres of each other, so grown straight up 90 % of them had their centre of
    mass outside their support and would fall over (docs/dataset.md)."""
    size = rng.uniform(0.5, 1.3)
    n_stems = int(rng.integers(3, 8))
    stems, twigs, foliage, axes = [], [], [], []
    for _ in range(n_stems):
        d = _unit(np.array([rng.normal(0, 0.7), rng.normal(0, 0.7), 1.0]))
        length = size * rng.uniform(0.35, 0.55)
        start = np.array([rng.normal(0, size * 0.03), rng.normal(0, size * 0.03), -0.01])
        end = start + d * length
        axes.append((start, end))
        stems.append(tapered_segment(start, end, size * 0.018, size * 0.01, 7))
        for _k in range(int(rng.integers(3, 6))):
            s = start + d * length * rng.uniform(0.35, 1.0)
            td = _upward_direction(rng, d, 0.9)
            tl = size * rng.uniform(0.15, 0.3)
            tip = s + td * tl
            twigs.append(tapered_segment(s, tip, size * 0.006, size * 0.003, 5))
            if rng.random() < 0.8:
                foliage += blob_cluster(rng, tip, size * rng.uniform(0.12, 0.2), int(rng.integers(2, 4)))
        foliage += blob_cluster(rng, end, size * 0.2, int(rng.integers(2, 4)))
    pieces = [Piece("stems", concatenate(stems), jitter(rng, pick(rng, BARK)), 0.05, weight=2.0),
              Piece("twigs", concatenate(twigs), jitter(rng, (0.50, 0.33, 0.22)), 0.05, weight=3.0),
              Piece("foliage", concatenate(foliage), jitter(rng, pick(rng, LEAF_GREENS), 0.1), 0.08)]
    turned = np.eye(3)
    for _ in range(BALANCE_ROUNDS):  # turn, plant the stems again, again (the centre of mass moves a little)
        T = balance_turn(pieces, np.mean([a for a, _ in axes], axis=0))
        turned = T[:3, :3] @ turned
        for piece in pieces[1:]:
            piece.mesh.apply_transform(T)
        axes = [(T[:3, :3] @ a + T[:3, 3], T[:3, :3] @ b + T[:3, 3]) for a, b in axes]
        # the ground: z = 0, or lower where foliage hanging on the low side reaches below it; the
        # stems go down to it (1 cm deep), so they carry the bush and foliage only touches
        ground = min(0.0, min(float(np.asarray(p.mesh.vertices)[:, 2].min()) for p in pieces[1:]))
        axes = [(planted(a, b, ground - 0.01), b) for a, b in axes]
        pieces[0].mesh = concatenate([tapered_segment(a, b, size * 0.018, size * 0.01, 7) for a, b in axes])
    for piece in pieces:
        piece.mesh.apply_translation([0.0, 0.0, -ground])
    turn = float(np.degrees(np.arccos(np.clip(turned[2, 2], -1.0, 1.0))))
    return pieces, _round({"size_m": size, "stems": n_stems, "foliage_blobs": len(foliage), "balance_deg": turn})


@recipe("grass_patch")
def grass_patch(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Patch 0.2–0.5 m in radius of 150–500 bending blades, optionally on a soil slab."""
    radius = rng.uniform(0.2, 0.5)
    pieces: list[Piece] = []
    ground = 0.0
    has_soil = "soil" in parts
    if has_soil:
        thick = rng.uniform(0.02, 0.05)
        bump = rng.uniform(0.0, 0.01)
        phase = rng.uniform(0, 2 * np.pi)
        slab = pile_slab(radius * 1.05, lambda r, t: 0.0 * r,
                         lambda r, t: thick + bump * np.sin(3 * t + phase) * (r / radius), rings=8, sections=32)
        pieces.append(Piece("soil", slab, jitter(rng, pick(rng, SOIL)), 0.06, fill=True, weight=0.5))
        ground = thick - 0.005
    n = int(rng.integers(150, 500))
    height = rng.uniform(0.08, 0.3)
    width = rng.uniform(0.004, 0.012)
    base_green = np.asarray(pick(rng, [(0.30, 0.55, 0.15), (0.40, 0.60, 0.20), (0.25, 0.45, 0.12),
                                       (0.55, 0.60, 0.25)]))
    groups: list[list[trimesh.Trimesh]] = [[], [], []]
    for i in range(n):
        r = radius * np.sqrt(rng.random())
        a = rng.uniform(0, 2 * np.pi)
        h = height * rng.uniform(0.5, 1.2)
        groups[i % 3].append(blade(np.array([r * np.cos(a), r * np.sin(a), ground]), h, width,
                                   rng.normal(0, 0.35, 2), segments=4))
    for g, tone in zip(groups, (0.85, 1.0, 1.15)):
        pieces.append(Piece("blades", concatenate(g), jitter(rng, np.clip(base_green * tone, 0, 1), 0.04),
                            0.05, weight=2.5))
    return pieces, _round({"radius_m": radius, "blades": n, "blade_height_m": height, "blade_width_m": width,
                           "soil": has_soil})


# ---------------------------------------------------------------------------------- toys and balls
@recipe("rubber_toy")
def rubber_toy(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Rubber duck (70 %) or a small jointed figure (30 %), 6–20 cm, solid."""
    size = rng.uniform(0.06, 0.2)
    if rng.random() < 0.7:
        body_rgb = jitter(rng, (0.98, 0.85, 0.10) if rng.random() < 0.75 else pick(rng, TOY_COLOURS))
        body = ellipsoid(np.array([0.0, 0.0, size * 0.3]), size * np.array([0.5, 0.36, 0.3]), 2)
        tail = ellipsoid(np.array([-size * 0.42, 0.0, size * 0.42]), size * np.array([0.15, 0.12, 0.1]), 1,
                         np.array([[0.8, 0, -0.6], [0, 1, 0], [0.6, 0, 0.8]]))
        head_c = np.array([size * 0.25, 0.0, size * 0.68])
        head = ellipsoid(head_c, np.full(3, size * 0.22), 2)
        beak = ellipsoid(head_c + np.array([size * 0.24, 0.0, -size * 0.03]), size * np.array([0.11, 0.08, 0.035]), 1)
        eyes = [ellipsoid(head_c + np.array([size * 0.15, s * size * 0.12, size * 0.08]), np.full(3, size * 0.03), 1)
                for s in (-1, 1)]
        # each closed component is its own piece: the interior test counts ray crossings, so
        # overlapping closed shells in one mesh would cancel inside their overlap
        pieces = [Piece("toy", m, body_rgb, 0.03, fill=True) for m in (body, tail, head)]
        pieces += [Piece("toy", beak, jitter(rng, (0.95, 0.45, 0.05)), 0.03, fill=True)]
        pieces += [Piece("toy", eye, (0.05, 0.05, 0.05), 0.02, fill=True, weight=2.0) for eye in eyes]
        return pieces, _round({"kind": "duck", "size_m": size, "body_rgb": [round(v, 3) for v in body_rgb]})
    rgb = jitter(rng, pick(rng, TOY_COLOURS))
    body = ellipsoid(np.array([0, 0, size * 0.45]), size * np.array([0.22, 0.18, 0.28]), 2)
    head_c = np.array([0, 0, size * 0.88])
    head = ellipsoid(head_c, np.full(3, size * 0.2), 2)
    ears = [ellipsoid(head_c + np.array([0, s * size * 0.15, size * 0.16]), np.full(3, size * 0.07), 1)
            for s in (-1, 1)]
    limbs = [ellipsoid(np.array([size * 0.05, s * size * 0.24, size * 0.5]), size * np.array([0.07, 0.07, 0.16]), 1)
             for s in (-1, 1)]
    limbs += [ellipsoid(np.array([size * 0.08, s * size * 0.1, size * 0.12]), size * np.array([0.09, 0.08, 0.13]), 1)
              for s in (-1, 1)]
    snout = ellipsoid(head_c + np.array([size * 0.17, 0, -size * 0.03]), size * np.array([0.07, 0.08, 0.06]), 1)
    pieces = [Piece("toy", m, rgb, 0.04, fill=True) for m in [body, head] + ears + limbs]
    pieces += [Piece("toy", snout, jitter(rng, (0.90, 0.80, 0.65)), 0.03, fill=True)]
    return pieces, _round({"kind": "figure", "size_m": size})


def _split_faces(mesh: trimesh.Trimesh, labels: np.ndarray) -> dict[int, trimesh.Trimesh]:
    """Sub-meshes of `mesh` by integer face label (for painted patterns on one surface)."""
    out = {}
    for lab in np.unique(labels):
        out[int(lab)] = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces[labels == lab], process=False)
    return out


BALLS = {  # radius (m), colours: base, pattern
    "soccer": (0.11, (0.95, 0.95, 0.95), (0.08, 0.08, 0.08)),
    "basketball": (0.12, (0.85, 0.42, 0.12), (0.10, 0.07, 0.05)),
    "tennis": (0.033, (0.80, 0.90, 0.20), (0.97, 0.97, 0.95)),
    "volleyball": (0.105, (0.97, 0.97, 0.95), (0.20, 0.35, 0.75)),
    "beach": (0.2, (0.95, 0.20, 0.20), (0.97, 0.97, 0.97)),
}


@recipe("sport_ball")
def sport_ball(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Hollow ball (shell): soccer, basketball, tennis, volleyball or beach ball with its pattern."""
    kind = pick(rng, list(BALLS))
    radius, base, pattern = BALLS[kind]
    radius *= rng.uniform(0.9, 1.1)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    c = sphere.triangles_center / radius
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    if kind == "soccer":
        dirs = trimesh.creation.icosahedron().vertices
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        labels = ((c @ dirs.T).max(axis=1) > 0.93).astype(int)
    elif kind == "basketball":
        labels = ((np.abs(x) < 0.05) | (np.abs(z) < 0.05) | (np.abs(np.hypot(x, z) - 0.75) < 0.05)).astype(int)
    elif kind == "tennis":
        seam = z - 0.6 * np.sin(2 * np.arctan2(y, x)) * np.sqrt(np.maximum(0, 1 - z ** 2))
        labels = (np.abs(seam) < 0.06).astype(int)
    elif kind == "volleyball":
        labels = (np.floor((np.arctan2(y, x) + np.pi) / (2 * np.pi / 3) + 0.5 * (z > 0)) % 2).astype(int)
    else:
        labels = (np.floor((np.arctan2(y, x) + np.pi) / (2 * np.pi / 6)) % 2).astype(int)
    sphere.vertices[:, 2] += radius
    sub = _split_faces(sphere, labels)
    colours = {0: jitter(rng, base, 0.04), 1: jitter(rng, pattern, 0.04)}
    if kind == "beach":
        colours[1] = jitter(rng, pick(rng, [(0.97, 0.97, 0.97), (0.2, 0.4, 0.9), (0.98, 0.85, 0.1)]))
    pieces = [Piece("ball", m, colours[k], 0.03) for k, m in sub.items()]
    return pieces, _round({"kind": kind, "radius_m": radius})


# ---------------------------------------------------------------------------------- metal shells
@recipe("soda_can")
def soda_can(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Aluminium can shell (r 2.6–3.4 cm): silver base and neck, painted body with label bands;
    a quarter of them lie on their side."""
    r = rng.uniform(0.026, 0.034)
    h = r * rng.uniform(3.3, 5.2)
    bottom = lathe(np.array([r * 0.8, r]), np.array([0.0, h * 0.03]), 32, cap_bottom=True, cap_top=False)
    neck = lathe(np.array([r, r * 0.86, r * 0.86]), np.array([h * 0.9, h * 0.97, h]), 32,
                 cap_bottom=False, cap_top=True)
    tab = box(np.array([r * 0.5, r * 0.25, 0.002]), np.array([r * 0.2, 0.0, h + 0.001]))
    paint = jitter(rng, pick(rng, CAN_PAINT), 0.05)
    accent = jitter(rng, pick(rng, CAN_PAINT + [(0.97, 0.97, 0.97)]), 0.05)
    z_cut = np.sort(rng.uniform(0.25, 0.8, 2))
    zs = h * np.concatenate([[0.03], 0.03 + 0.87 * z_cut, [0.9]])
    pieces = [Piece("can", concatenate([bottom, neck, tab]), jitter(rng, ALUMINIUM, 0.03), 0.03)]
    for k in range(3):
        band = lathe(np.array([r, r]), zs[k:k + 2], 32, cap_bottom=False, cap_top=False)
        pieces.append(Piece("can", band, paint if k != 1 else accent, 0.03))
    lying = rng.random() < 0.25
    if lying:
        lay_on_side(pieces, h, r)
    return pieces, _round({"radius_m": r, "height_m": h, "lying": lying})


def lay_on_side(pieces: list[Piece], height_m: float, radius_m: float) -> None:
    """Turn an upright (z-axis) cylinder-like object of `height_m` and `radius_m` onto its side,
    resting on the ground (z = 0) and centred where it stood."""
    T = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])
    T[:3, 3] = [0.0, height_m / 2, radius_m]
    for piece in pieces:
        piece.mesh.apply_transform(T)


@recipe("metal_crate")
def metal_crate(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Sheet-metal crate 0.3–1 m: thin walls (open top half of the time), edge frame and ribs."""
    ext = np.array([rng.uniform(0.4, 1.0), rng.uniform(0.3, 0.8), rng.uniform(0.3, 0.7)])
    t = rng.uniform(0.006, 0.015)
    open_top = rng.random() < 0.5
    lx, ly, lz = ext
    walls = [box(np.array([lx, ly, t]), np.array([0, 0, t / 2])),
             box(np.array([t, ly, lz]), np.array([lx / 2 - t / 2, 0, lz / 2])),
             box(np.array([t, ly, lz]), np.array([-lx / 2 + t / 2, 0, lz / 2])),
             box(np.array([lx, t, lz]), np.array([0, ly / 2 - t / 2, lz / 2])),
             box(np.array([lx, t, lz]), np.array([0, -ly / 2 + t / 2, lz / 2]))]
    if not open_top:
        walls.append(box(np.array([lx, ly, t]), np.array([0, 0, lz - t / 2])))
    f = t * 2.5
    frame = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            frame.append(box(np.array([f, f, lz]), np.array([sx * (lx / 2 - f / 2), sy * (ly / 2 - f / 2), lz / 2])))
    for z in (f / 2, lz - f / 2):
        for sy in (-1, 1):
            frame.append(box(np.array([lx, f, f]), np.array([0, sy * (ly / 2 - f / 2), z])))
        for sx in (-1, 1):
            frame.append(box(np.array([f, ly, f]), np.array([sx * (lx / 2 - f / 2), 0, z])))
    ribs = int(rng.integers(0, 4))
    for k in range(ribs):
        z = lz * (k + 1) / (ribs + 1)
        for sy in (-1, 1):
            frame.append(box(np.array([lx * 0.98, f * 0.8, f * 0.6]), np.array([0, sy * ly / 2, z])))
    metal = jitter(rng, pick(rng, CRATE_METAL), 0.05)
    trim = jitter(rng, np.asarray(metal) * rng.uniform(0.55, 0.8), 0.03)
    pieces = [Piece("crate", concatenate(walls), metal, 0.05),
              Piece("crate", concatenate(frame), trim, 0.04, weight=1.5)]
    return pieces, _round({"length_m": lx, "width_m": ly, "height_m": lz, "wall_m": t, "open_top": open_top,
                           "ribs": ribs})


# ---------------------------------------------------------------------------------- piles
def _pile_surface(rng: np.random.Generator, radius: float, height: float):
    """Height field h(r, θ) of a noisy mound: h0·(1 − (r/R)^p) plus angular ripples."""
    p = rng.uniform(1.2, 2.5)
    amps = rng.uniform(0.0, 0.12, 3)
    phases = rng.uniform(0, 2 * np.pi, 3)

    def h(r, th):
        s = np.clip(r / radius, 0.0, 1.0)
        ripple = sum(a * np.sin((k + 2) * th + ph) for k, (a, ph) in enumerate(zip(amps, phases)))
        return height * (1.0 - s ** p) * (1.0 + ripple * s)
    return h, p


@recipe("sand_pile")
def sand_pile(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Filled sand heap (radius 0.2–0.8 m, slope from cone to dome, rippled, sometimes elongated)."""
    radius = rng.uniform(0.2, 0.8)
    height = radius * rng.uniform(0.3, 0.7)
    h, p = _pile_surface(rng, radius, height)
    mesh = pile_slab(radius, lambda r, t: 0.0 * r, h)
    stretch = rng.uniform(1.0, 1.6)
    mesh.vertices[:, 0] *= stretch
    pieces = [Piece("sand", mesh, jitter(rng, pick(rng, SAND), 0.05), 0.05, fill=True)]
    return pieces, _round({"radius_m": radius, "height_m": height, "profile_power": p, "stretch": stretch})


@recipe("snow_mud_pile")
def snow_mud_pile(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Filled mound of mud with a snow cap that leaves a muddy rim (both parts solid)."""
    radius = rng.uniform(0.25, 0.8)
    mud_h = radius * rng.uniform(0.15, 0.35)
    snow_h = radius * rng.uniform(0.1, 0.3)
    cover = rng.uniform(0.6, 0.9)
    mud_surface, p = _pile_surface(rng, radius, mud_h)
    snow_r = radius * cover

    def snow_top(r, th):
        s = np.clip(r / snow_r, 0.0, 1.0)
        return mud_surface(r, th) + snow_h * (1.0 - s ** 2)

    pieces = [Piece("mud", pile_slab(radius, lambda r, t: 0.0 * r, mud_surface), jitter(rng, pick(rng, MUD)),
                    0.07, fill=True),
              Piece("snow", pile_slab(snow_r, mud_surface, snow_top), jitter(rng, pick(rng, SNOW), 0.03),
                    0.05, fill=True)]
    return pieces, _round({"radius_m": radius, "mud_height_m": mud_h, "snow_height_m": snow_h,
                           "snow_cover": cover})
