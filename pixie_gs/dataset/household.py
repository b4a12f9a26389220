"""Geometry recipes of everyday objects (issue 12): wooden furniture and instruments, ceramic and glass
ware, bottles, plastic toys, cushions, stones, bread, fruit, cardboard and books; steel hand tools, cloth
and long fruit and vegetables.

Same conventions as shapes.py: metres, z up, objects stand on z = 0 centred on x = y = 0, one
`Piece` per coloured mesh; closed meshes may be filled. Importing this module registers the recipes.
"""
from __future__ import annotations

import math

import numpy as np
import trimesh

from .primitives import box, concatenate, ellipsoid, lathe, tapered_segment
from .shapes import Piece, _round, jitter, lay_on_side, pick, recipe

WOODS = [(0.55, 0.38, 0.22), (0.45, 0.30, 0.18), (0.68, 0.52, 0.34), (0.35, 0.22, 0.13), (0.78, 0.64, 0.45),
         (0.25, 0.16, 0.10)]
PAINTED_WOOD = [(0.92, 0.92, 0.90), (0.15, 0.15, 0.16), (0.30, 0.40, 0.55)]
CERAMIC = [(0.95, 0.95, 0.93), (0.90, 0.88, 0.82), (0.30, 0.45, 0.70), (0.75, 0.35, 0.25), (0.20, 0.22, 0.25),
           (0.60, 0.75, 0.65), (0.85, 0.80, 0.60)]
GLASS = [(0.35, 0.55, 0.35), (0.45, 0.30, 0.15), (0.80, 0.85, 0.85), (0.25, 0.40, 0.60)]
PLASTIC = [(0.95, 0.20, 0.20), (0.15, 0.45, 0.90), (0.98, 0.85, 0.10), (0.20, 0.75, 0.35), (0.98, 0.98, 0.98),
           (0.95, 0.50, 0.10), (0.55, 0.25, 0.75)]
STEEL = [(0.70, 0.72, 0.75), (0.55, 0.57, 0.60), (0.82, 0.83, 0.85), (0.20, 0.20, 0.22)]
FABRIC = [(0.70, 0.25, 0.25), (0.30, 0.40, 0.60), (0.85, 0.80, 0.70), (0.40, 0.55, 0.40), (0.55, 0.45, 0.60),
          (0.90, 0.70, 0.30), (0.50, 0.50, 0.52)]
STONE = [(0.50, 0.50, 0.48), (0.42, 0.40, 0.37), (0.62, 0.58, 0.52), (0.35, 0.35, 0.36), (0.58, 0.50, 0.42)]
CRUST = [(0.72, 0.48, 0.22), (0.60, 0.38, 0.18), (0.80, 0.60, 0.32), (0.50, 0.30, 0.15)]
ICING = [(0.95, 0.60, 0.75), (0.40, 0.25, 0.15), (0.97, 0.95, 0.92), (0.90, 0.80, 0.30), (0.75, 0.52, 0.78)]
DONUT_DOUGH = [(0.80, 0.70, 0.52), (0.86, 0.76, 0.58), (0.76, 0.62, 0.42)]  # pale fried dough under icing
SPRINKLES = [(0.20, 0.35, 0.85), (0.95, 0.20, 0.25), (0.98, 0.85, 0.15), (0.25, 0.75, 0.35), (0.97, 0.97, 0.97),
             (0.60, 0.25, 0.75)]
FRUIT = [(0.80, 0.10, 0.12), (0.95, 0.55, 0.10), (0.55, 0.75, 0.20), (0.95, 0.85, 0.25), (0.45, 0.15, 0.35)]
CARDBOARD = [(0.70, 0.55, 0.38), (0.62, 0.48, 0.32), (0.78, 0.65, 0.48)]
PAPER = [(0.95, 0.94, 0.90), (0.90, 0.88, 0.80)]
COVERS = [(0.60, 0.10, 0.12), (0.10, 0.25, 0.50), (0.15, 0.40, 0.20), (0.20, 0.20, 0.22), (0.85, 0.70, 0.30)]


def _rot(axis, angle: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, axis, point=centre)


# ------------------------------------------------------------------------------------ wood
@recipe("table")
def table(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Table 0.4–2 m long: a top slab on four legs (round top a third of the time), optional apron."""
    h = rng.uniform(0.4, 0.8)
    lx, ly = rng.uniform(0.5, 2.0), rng.uniform(0.4, 1.0)
    t = rng.uniform(0.025, 0.06)
    leg = rng.uniform(0.03, 0.07)
    wood = jitter(rng, pick(rng, WOODS + PAINTED_WOOD[:1]), 0.08)
    if rng.random() < 0.33:
        top = lathe(np.array([lx / 2, lx / 2]), np.array([h - t, h]), 40)
        spots = [(math.cos(a) * lx * 0.3, math.sin(a) * lx * 0.3) for a in np.arange(4) * math.pi / 2 + 0.7]
    else:
        top = box(np.array([lx, ly, t]), np.array([0, 0, h - t / 2]))
        spots = [(sx * (lx / 2 - leg), sy * (ly / 2 - leg)) for sx in (-1, 1) for sy in (-1, 1)]
    legs = [box(np.array([leg, leg, h - t]), np.array([x, y, (h - t) / 2])) for x, y in spots]
    pieces = [Piece("wood", top, wood, 0.05), Piece("wood", concatenate(legs), jitter(rng, wood, 0.04), 0.05)]
    return pieces, _round({"height_m": h, "length_m": lx, "width_m": ly})


@recipe("chair")
def chair(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Wooden chair: seat 0.35–0.5 m at 0.4–0.5 m, four legs, back rest with slats."""
    s = rng.uniform(0.35, 0.5)
    hs = rng.uniform(0.4, 0.5)
    hb = rng.uniform(0.35, 0.55)
    t, leg = rng.uniform(0.02, 0.04), rng.uniform(0.025, 0.045)
    wood = jitter(rng, pick(rng, WOODS + PAINTED_WOOD), 0.08)
    seat = box(np.array([s, s, t]), np.array([0, 0, hs - t / 2]))
    legs = [box(np.array([leg, leg, hs - t]), np.array([sx * (s / 2 - leg), sy * (s / 2 - leg), (hs - t) / 2]))
            for sx in (-1, 1) for sy in (-1, 1)]
    posts = [box(np.array([leg, leg, hb]), np.array([-s / 2 + leg / 2, sy * (s / 2 - leg), hs + hb / 2]))
             for sy in (-1, 1)]
    slats = [box(np.array([t, s - 2 * leg, rng.uniform(0.04, 0.1)]), np.array([-s / 2 + leg / 2, 0, hs + hb * f]))
             for f in np.linspace(0.4, 0.9, int(rng.integers(1, 4)))]
    pieces = [Piece("wood", concatenate([seat] + legs), wood, 0.05),
              Piece("wood", concatenate(posts + slats), jitter(rng, wood, 0.04), 0.05)]
    return pieces, _round({"seat_m": s, "seat_height_m": hs})


@recipe("guitar")
def guitar(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Acoustic/electric guitar 0.9–1.1 m standing upright on its lower bout, with an optional
    metal stand (a tubular A-frame behind it, tubes 16–28 mm)."""
    L = rng.uniform(0.9, 1.1)
    depth = rng.uniform(0.05, 0.11)
    lower, upper = rng.uniform(0.17, 0.21), rng.uniform(0.13, 0.16)
    wood = jitter(rng, pick(rng, WOODS + [(0.85, 0.55, 0.20), (0.70, 0.15, 0.10), (0.10, 0.10, 0.10)]), 0.06)
    base = 0.06 if "stand" in parts else 0.0
    bout_lo = ellipsoid(np.array([0, 0, base + lower]), np.array([lower, depth / 2, lower * 0.95]), 2)
    bout_hi = ellipsoid(np.array([0, 0, base + 1.9 * lower]), np.array([upper, depth / 2, upper * 0.9]), 2)
    z_neck = base + 1.9 * lower + upper * 0.7
    neck = box(np.array([0.05, 0.03, L - (z_neck - base)]), np.array([0, 0, (z_neck + base + L) / 2]))
    head = box(np.array([0.08, 0.025, 0.16]), np.array([0, 0, base + L + 0.07]))
    hole = lathe(np.array([0.045, 0.045]), np.array([0.0, 0.002]), 20, cap_bottom=True, cap_top=True)
    hole.apply_transform(_rot([1, 0, 0], math.pi / 2))
    hole.apply_transform(trimesh.transformations.translation_matrix([0, -depth / 2 - 0.002, base + 1.45 * lower]))
    pieces = [Piece("body", bout_lo, wood, 0.04, fill=True), Piece("body", bout_hi, wood, 0.04, fill=True),
              Piece("body", concatenate([neck, head]), jitter(rng, pick(rng, WOODS), 0.05), 0.04),
              Piece("body", hole, (0.08, 0.06, 0.05), 0.02, weight=2.0)]
    if "stand" in parts:
        steel = jitter(rng, pick(rng, STEEL), 0.04)
        r = rng.uniform(0.008, 0.014)  # tube radius, m
        rails = [tapered_segment(np.array([sx * 0.18, 0.05, 0.0]), np.array([0, 0.12, 0.75 * L]), r, r, 8)
                 for sx in (-1, 1)]
        rails += [tapered_segment(np.array([-0.2, -0.05, base]), np.array([0.2, -0.05, base]), r, r, 8),
                  tapered_segment(np.array([0, 0.05, 0.02]), np.array([0, 0.3, 0.0]), r, r, 8)]
        pieces.append(Piece("stand", concatenate(rails), steel, 0.03, weight=1.5))
    return pieces, _round({"length_m": L, "depth_m": depth, "stand": "stand" in parts})


@recipe("picture_frame")
def picture_frame(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Upright wooden frame 0.2–1 m wide and high (drawn alike) with a picture (paper/canvas) inside.

    `equal_law_ups` (recipe frame, before yaw and scale): the ups under which a frame is as likely a
    draw of this recipe as standing as built — a quarter turn in its plane swaps width and height,
    which are drawn from the same range, so no shape cue can say portrait from landscape."""
    w, h = rng.uniform(0.2, 1.0), rng.uniform(0.2, 1.0)
    b, d = rng.uniform(0.02, 0.07), rng.uniform(0.015, 0.04)
    wood = jitter(rng, pick(rng, WOODS + PAINTED_WOOD), 0.06)
    bars = [box(np.array([w, d, b]), np.array([0, 0, b / 2])), box(np.array([w, d, b]), np.array([0, 0, h - b / 2])),
            box(np.array([b, d, h - 2 * b]), np.array([-w / 2 + b / 2, 0, h / 2])),
            box(np.array([b, d, h - 2 * b]), np.array([w / 2 - b / 2, 0, h / 2]))]
    pieces = [Piece("frame", concatenate(bars), wood, 0.05)]
    if "picture" in parts:
        pic = box(np.array([w - 2 * b, 0.004, h - 2 * b]), np.array([0, 0, h / 2]))
        pieces.append(Piece("picture", pic, jitter(rng, tuple(rng.uniform(0.1, 0.9, 3)), 0.1), 0.15))
    return pieces, _round({"width_m": w, "height_m": h, "bar_m": b, "equal_law_ups": [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]})


# ------------------------------------------------------------------------------------ ceramic, glass, bottles
def _vessel(rng: np.random.Generator, height: float, radius: float, neck: float) -> trimesh.Trimesh:
    """Shell of revolution: foot, belly, shoulder, neck to lip (open top)."""
    belly = rng.uniform(0.3, 0.6)
    r = radius * np.array([rng.uniform(0.5, 0.8), 1.0, rng.uniform(0.6, 1.0), neck, neck * rng.uniform(1.0, 1.3)])
    z = height * np.array([0.0, belly, min(belly + 0.25, 0.85), 0.92, 1.0])
    return lathe(r, z, 32, cap_bottom=True, cap_top=False)


@recipe("vase")
def vase(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Ceramic/porcelain vase 0.15–0.6 m (shell), plain or with a painted band."""
    h = rng.uniform(0.15, 0.6)
    r = h * rng.uniform(0.18, 0.4)
    shell = _vessel(rng, h, r, rng.uniform(0.3, 0.8))
    glaze = jitter(rng, pick(rng, CERAMIC), 0.05)
    pieces = [Piece("body", shell, glaze, 0.03)]
    if rng.random() < 0.4:
        band = lathe(np.array([r * 1.01, r * 1.01]), h * np.array([0.4, 0.5]), 32, cap_bottom=False, cap_top=False)
        pieces.append(Piece("body", band, jitter(rng, pick(rng, CERAMIC), 0.05), 0.03))
    return pieces, _round({"height_m": h, "radius_m": r})


@recipe("mug")
def mug(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Ceramic mug or cup 7–12 cm (shell) with a handle; sometimes a bowl instead."""
    h = rng.uniform(0.07, 0.12)
    r = rng.uniform(0.035, 0.05)
    glaze = jitter(rng, pick(rng, CERAMIC), 0.05)
    if rng.random() < 0.3:  # bowl
        shell = lathe(np.array([r * 0.8, r * 1.6, r * 2.0]), np.array([0.0, h * 0.4, h * 0.7]), 32, True, False)
        return [Piece("body", shell, glaze, 0.03)], _round({"kind": "bowl", "radius_m": r})
    shell = lathe(np.array([r * 0.9, r, r]), np.array([0.0, 0.01, h]), 32, True, False)
    handle = trimesh.creation.torus(h * 0.28, h * 0.06, major_sections=24, minor_sections=8)
    handle.apply_transform(_rot([1, 0, 0], math.pi / 2))
    handle.apply_transform(trimesh.transformations.translation_matrix([r + h * 0.15, 0, h * 0.5]))
    return [Piece("body", shell, glaze, 0.03), Piece("body", handle, glaze, 0.03)], _round({"kind": "mug", "radius_m": r})


@recipe("bottle")
def bottle(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Bottle 0.15–0.35 m (shell: body, shoulder, neck) with a cap and often a label band; a fifth
    lie on their side. The colour palette comes from the part name (glass, plastic or metal)."""
    (part,) = tuple(parts)
    h = rng.uniform(0.15, 0.35)
    r = h * rng.uniform(0.12, 0.2)
    neck = rng.uniform(0.25, 0.45)
    if part == "metal":  # drinking flask: wide neck, high shoulder
        r, neck = h * rng.uniform(0.13, 0.18), rng.uniform(0.6, 0.85)
    palette = {"glass": GLASS, "plastic": PLASTIC, "metal": STEEL + [(0.15, 0.35, 0.55), (0.60, 0.15, 0.15)]}
    colour = jitter(rng, pick(rng, palette.get(part, GLASS)), 0.05)
    sh = rng.uniform(0.55, 0.75) if part != "metal" else rng.uniform(0.78, 0.86)
    body = lathe(r * np.array([0.95, 1.0, 1.0, neck, neck]), h * np.array([0.0, 0.02, sh, sh + 0.2, 0.93]), 32,
                 True, False)
    cap = lathe(np.full(2, r * neck * 1.1), h * np.array([0.93, 1.0]), 20)
    pieces = [Piece(part, body, colour, 0.03), Piece(part, cap, jitter(rng, pick(rng, PLASTIC + STEEL), 0.05), 0.03)]
    if rng.random() < 0.6:
        band = lathe(np.full(2, r * 1.01), h * np.sort(rng.uniform(0.15, 0.55, 2)), 32, False, False)
        pieces.append(Piece(part, band, jitter(rng, tuple(rng.uniform(0.1, 0.95, 3)), 0.05), 0.05))
    lying = rng.random() < 0.2
    if lying:
        lay_on_side(pieces, h, r)
    return pieces, _round({"height_m": h, "radius_m": r, "lying": lying})


# ------------------------------------------------------------------------------------ soft and natural things
@recipe("plastic_toy")
def plastic_toy(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Hard-plastic toy bricks (2–8 stacked blocks with studs) or a toy car body."""
    pieces = []
    z = 0.0
    u = rng.uniform(0.016, 0.04)
    for k in range(int(rng.integers(2, 9))):
        nx, ny = int(rng.integers(1, 4)), int(rng.integers(1, 3))
        ext = np.array([nx * 2 * u, ny * 2 * u, 1.2 * u])
        off = rng.uniform(-u, u, 2) * (k > 0)
        blk = box(ext, np.array([off[0], off[1], z + ext[2] / 2]))
        studs = [lathe(np.full(2, u * 0.3), np.array([z + ext[2], z + ext[2] + u * 0.35]), 12)
                 for _ in range(1)]
        for s, (i, j) in zip(studs, [(0, 0)]):
            s.apply_transform(trimesh.transformations.translation_matrix([off[0], off[1], 0]))
        pieces.append(Piece("toy", concatenate([blk] + studs), jitter(rng, pick(rng, PLASTIC), 0.04), 0.03))
        z += ext[2]
    return pieces, _round({"unit_m": u, "blocks": len(pieces)})


@recipe("cushion")
def cushion(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Fabric cushion or pillow 0.3–0.7 m (filled, puffy), lying flat.

    No cushion leans: until this change 30 % stood tilted 46–75° on one edge, a pose that needs a
    wall or a sofa back the object does not include (its centre of mass is not above that edge, so
    it falls flat; tests/test_generate.py checks every class rests on its own support). The draws
    of the old lean are kept, so every other cushion is the same as before."""
    a, b = rng.uniform(0.15, 0.35), rng.uniform(0.15, 0.35)
    c = rng.uniform(0.05, 0.12)
    fabric = jitter(rng, pick(rng, FABRIC), 0.06)
    m = trimesh.creation.icosphere(2, 1.0)
    v = m.vertices.copy()
    v = np.sign(v) * np.abs(v) ** 0.6  # squarer than an ellipsoid
    v *= np.array([a, b, c])
    m = trimesh.Trimesh(v + np.array([0, 0, c]), m.faces.copy(), process=False)
    if rng.random() < 0.3:  # the old lean's draws (see the docstring)
        rng.uniform(0.8, 1.3)
    return [Piece("fabric", m, fabric, 0.06, fill=True)], _round({"half_size_m": [a, b, c]})


@recipe("stone")
def stone(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """A rock or boulder 0.1–1 m: a noisy, flattened icosphere (filled); sometimes a small cairn of 2–4."""
    pieces = []
    z = 0.0
    count = 1 if rng.random() < 0.7 else int(rng.integers(2, 5))
    size = rng.uniform(0.05, 0.5)
    colour = jitter(rng, pick(rng, STONE), 0.08)
    for k in range(count):
        s = size * (0.8 ** k)
        m = trimesh.creation.icosphere(2, 1.0)
        d = m.vertices @ rng.normal(0, 1, (3, 4))
        bump = 1.0 + 0.12 * np.tanh(d).sum(1) / 2 + rng.normal(0, 0.03, len(m.vertices))
        v = m.vertices * bump[:, None] * s * np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.8)])
        v[:, 2] += z - v[:, 2].min()
        z = v[:, 2].max() * 0.95
        pieces.append(Piece("stone", trimesh.Trimesh(v, m.faces.copy(), process=False),
                            jitter(rng, colour, 0.05), 0.08, fill=True))
    return pieces, _round({"size_m": size, "count": count})


def _donut(rng: np.random.Generator, crust: tuple[float, float, float]) -> tuple[list[Piece], dict]:
    """A doughnut ring 8–25 cm across, its tube 0.4–0.8 of the ring radius, with icing (70 %) over the top
    third to most of the ring and sprinkles on the icing (half of the iced ones, 40 to 1,500 of them); every
    piece is dough."""
    R = rng.uniform(0.04, 0.08)
    tube = R * rng.uniform(0.4, 0.8)
    dough_rgb = jitter(rng, pick(rng, DONUT_DOUGH), 0.05) if rng.random() < 0.5 else crust
    ring = trimesh.creation.torus(R, tube, major_sections=32, minor_sections=16)
    ring.apply_translation([0, 0, -ring.vertices[:, 2].min()])
    pieces = [Piece("dough", ring, dough_rgb, 0.05, fill=True)]
    iced = rng.random() < 0.7
    sprinkles = 0
    if iced:
        ice = tube * 1.04  # icing tube radius (m): 4 % thicker than the ring, bottom level with it: a shell
        top = trimesh.creation.torus(R, ice, major_sections=32, minor_sections=16)
        top.apply_translation([0, 0, ice])
        keep = top.vertices[:, 2] > tube * rng.uniform(0.3, 1.3)  # from the top third to most of the ring
        faces = top.faces[keep[top.faces].all(1)]
        pieces.append(Piece("dough", trimesh.Trimesh(top.vertices, faces, process=False),
                            jitter(rng, pick(rng, ICING), 0.05), 0.08, weight=1.5))
        if rng.random() < 0.5:
            sprinkles = int(np.exp(rng.uniform(np.log(40), np.log(1500))))  # sparse to a dense coat (a real one)
            lift = ice + 0.002  # sprinkles anywhere on the icing's upper band (sin φ > 0.44), 2 mm above it
            colours = [pick(rng, SPRINKLES) for _ in range(int(rng.integers(1, 4)))]
            groups: list[list[trimesh.Trimesh]] = [[] for _ in colours]
            for k in range(sprinkles):
                theta, phi = rng.uniform(0, 2 * np.pi), rng.uniform(0.46, np.pi - 0.46)
                rho = R + lift * np.cos(phi)
                p = np.array([rho * np.cos(theta), rho * np.sin(theta), ice + lift * np.sin(phi)])
                a = rng.uniform(0, 2 * np.pi)
                half = rng.uniform(0.002, 0.004) * np.array([np.cos(a), np.sin(a), 0.0])
                groups[k % len(colours)].append(tapered_segment(p - half, p + half, 0.0012, 0.0012, 5))
            pieces += [Piece("dough", concatenate(g), c, 0.04, weight=2.0) for g, c in zip(groups, colours) if g]
    return pieces, _round({"kind": "donut", "radius_m": R, "tube_m": tube, "iced": iced, "sprinkles": sprinkles})


@recipe("bread")
def bread(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Baked goods, filled: a loaf or baguette (crust), a bun, or a doughnut ring (thin to fat, pale or
    brown dough) with icing, often with sprinkles; two in five are doughnuts. The pale dough, fat rings,
    sprinkles and icing that covers most of the ring came in after a real doughnut capture (pale ring,
    lilac icing over two thirds of it, blue sprinkles) read as hard plastic: recoloured brown, the same
    capture reads as bread."""
    kind = pick(rng, ["loaf", "baguette", "bun", "donut", "donut"])
    crust = jitter(rng, pick(rng, CRUST), 0.06)
    if kind == "donut":
        return _donut(rng, crust)
    dims = {"loaf": (0.12, 0.07, 0.06), "baguette": (0.3, 0.035, 0.03), "bun": (0.05, 0.05, 0.035)}[kind]
    r = np.array(dims) * rng.uniform(0.8, 1.25)
    m = ellipsoid(np.array([0, 0, r[2]]), r, 2)
    v = m.vertices.copy()
    v[:, 2] = np.maximum(v[:, 2], r[2] * 0.35)  # flat bottom
    m = trimesh.Trimesh(v, m.faces.copy(), process=False)
    return [Piece("dough", m, crust, 0.06, fill=True)], _round({"kind": kind, "size_m": [float(x) for x in r]})


@recipe("fruit")
def fruit(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """One to five pieces of fruit (apple, orange, pear-like), filled, with a small stalk, each resting
    on the ground (until this change a piece's centre was at 0.95 × its radius whatever its
    height, so pieces floated up to 0.1 r above the ground or sank 0.2 r into it, and a pile of
    several stood on its lowest piece alone with its centre of mass off it: it would roll over)."""
    pieces = []
    n = int(rng.integers(1, 6))
    for k in range(n):
        r = rng.uniform(0.03, 0.05)
        x, y = rng.uniform(-0.08, 0.08) * (k > 0), rng.uniform(-0.08, 0.08) * (k > 0)
        squash = rng.uniform(0.85, 1.15)  # vertical semi-axis over r
        c = np.array([x, y, r * squash])
        m = ellipsoid(c, r * np.array([1.0, 1.0, squash]), 2)
        pieces.append(Piece("flesh", m, jitter(rng, pick(rng, FRUIT), 0.08), 0.05, fill=True))
        top = c + np.array([0.0, 0.0, r * squash])  # the stalk starts just inside the top (it floated above squat ones)
        stalk = tapered_segment(top - np.array([0, 0, r * 0.05]), top + np.array([0, 0, r * 0.3]), 0.003, 0.002, 6)
        pieces.append(Piece("flesh", stalk, (0.35, 0.25, 0.12), 0.03))
    return pieces, _round({"pieces": n})


@recipe("carton")
def carton(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Cardboard box 0.15–0.7 m (shell), closed or with open flaps, with a tape stripe."""
    ext = np.array([rng.uniform(0.15, 0.7), rng.uniform(0.15, 0.6), rng.uniform(0.1, 0.5)])
    brown = jitter(rng, pick(rng, CARDBOARD), 0.05)
    shell = box(ext, np.array([0, 0, ext[2] / 2]))
    pieces = [Piece("cardboard", shell, brown, 0.05)]
    tape = box(np.array([ext[0] * 1.002, 0.05, 0.002]), np.array([0, 0, ext[2] + 0.001]))
    pieces.append(Piece("cardboard", tape, jitter(rng, (0.80, 0.70, 0.50), 0.05), 0.03))
    return pieces, _round({"size_m": [float(x) for x in ext]})


@recipe("books")
def books(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """A stack or a row of 1–8 books: paper block with a coloured cover (each filled).

    `equal_law_ups` (recipe frame): a stack turned upside down is another stack drawn with the same
    probability (sizes independent, offsets symmetric, each book the same both ways up), so its
    shape cannot say which end was the bottom; a row stands on the common base of its books."""
    pieces = []
    upright = rng.random() < 0.5
    pos = 0.0
    n = int(rng.integers(1, 9))
    for _ in range(n):
        w, h, t = rng.uniform(0.12, 0.25), rng.uniform(0.17, 0.32), rng.uniform(0.01, 0.06)
        if upright:
            ext, centre = np.array([t, w, h]), np.array([pos + t / 2, 0, h / 2])
            pos += t
        else:
            ext, centre = np.array([h, w, t]), np.array([rng.uniform(-0.02, 0.02), 0, pos + t / 2])
            pos += t
        cover = jitter(rng, pick(rng, COVERS), 0.06)
        pieces.append(Piece("paper", box(ext, centre), cover, 0.04, fill=True))
        pages = box(ext * np.array([0.96 if upright else 1.01, 1.01, 0.96 if not upright else 1.0]) * 0.99, centre)
        pieces.append(Piece("paper", pages, jitter(rng, pick(rng, PAPER), 0.03), 0.03, weight=0.3))
    return pieces, _round({"books": n, "upright": upright, "equal_law_ups": [] if upright else [[0.0, 0.0, -1.0]]})


# ------------------------------------------------------------------------------------ tools, cloth, long produce
# Added after a third real set (benchmarks/real_third) showed three everyday kinds the vocabulary lacked:
# steel hand tools (read as wood at ~1,000 kg/m³), hanging cloth (read as a wooden board) and long fruit and
# vegetables (read as hard plastic). The recipes are generic kinds, not copies of those assets.
GRIPS = [(0.10, 0.10, 0.10), (0.80, 0.15, 0.12), (0.95, 0.75, 0.10), (0.15, 0.35, 0.75)]
PRODUCE = {"banana": [(0.95, 0.82, 0.22), (0.88, 0.78, 0.25), (0.72, 0.78, 0.28)],
           "cucumber": [(0.16, 0.36, 0.13), (0.30, 0.50, 0.18)], "carrot": [(0.95, 0.50, 0.10), (0.90, 0.40, 0.08)],
           "aubergine": [(0.25, 0.10, 0.25), (0.35, 0.15, 0.35)]}


@recipe("hand_tool")
def hand_tool(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """A hand tool 0.12–0.4 m lying flat: a hammer, screwdriver, knife or pair of scissors (steel working
    part, wooden or plastic handle), or an all-steel spanner when the handle part is absent."""
    steel = jitter(rng, pick(rng, STEEL), 0.05)
    grip = jitter(rng, pick(rng, WOODS + GRIPS), 0.06)
    kind = pick(rng, ["hammer", "screwdriver", "knife", "scissors"]) if "handle" in parts else "spanner"
    r = rng.uniform(0.008, 0.016)  # handle radius, m
    if kind == "hammer":
        L = rng.uniform(0.25, 0.4)
        handle = tapered_segment(np.array([-L / 2, 0, r]), np.array([L / 2, 0, r]), r, r * 0.85, 10)
        head = box(np.array([2.2 * r, rng.uniform(0.08, 0.13), 2 * r]), np.array([L / 2 + r, 0, r]))
        metal, holder = [head], [handle]
    elif kind == "screwdriver":
        L = rng.uniform(0.1, 0.18)
        handle = tapered_segment(np.array([-L, 0, r]), np.array([0, 0, r]), r, r * 0.8, 10)
        shaft = tapered_segment(np.array([0, 0, r]), np.array([rng.uniform(0.07, 0.2), 0, r]), 0.003, 0.0025, 6)
        metal, holder = [shaft], [handle]
    elif kind == "knife":
        L, w = rng.uniform(0.1, 0.22), rng.uniform(0.015, 0.04)
        handle = box(np.array([rng.uniform(0.09, 0.13), 1.6 * r, 1.2 * r]), np.array([-0.06, 0, 0.6 * r]))
        metal, holder = [box(np.array([L, w, 0.002]), np.array([L / 2, w / 2 - 0.006, 0.001]))], [handle]
    elif kind == "scissors":
        L = rng.uniform(0.07, 0.13)
        a = rng.uniform(0.05, 0.3)  # half opening angle, rad
        metal = [box(np.array([L, 0.012, 0.003]), np.array([L / 2, 0, 0.0015])) for _ in range(2)]
        for k, m in enumerate(metal):
            m.apply_transform(trimesh.transformations.rotation_matrix((2 * k - 1) * a, [0, 0, 1]))
        holder = []
        for k in (-1, 1):
            ring = trimesh.creation.annulus(0.011, 0.02, 0.006, sections=16)
            ring.apply_transform(trimesh.transformations.translation_matrix([-0.03, k * 0.018, 0.003]))
            holder.append(ring)
    else:
        L = rng.uniform(0.12, 0.3)
        bar = box(np.array([L, rng.uniform(0.012, 0.025), 0.006]), np.array([0, 0, 0.003]))
        jaws = [trimesh.creation.annulus(0.008, 0.016, 0.006, sections=16) for _ in (0, 1)]
        for k, j in zip((-1, 1), jaws):
            j.apply_transform(trimesh.transformations.translation_matrix([k * L / 2, 0, 0.003]))
        metal, holder = [bar] + jaws, []
    pieces = [Piece("steel", concatenate(metal), steel, 0.03, fill=True, weight=1.5)]
    if holder:
        pieces.append(Piece("handle", concatenate(holder), grip, 0.04, fill=True))
    return pieces, _round({"kind": kind, "length_m": L})


def _sheet(width: float, height: float, amplitude: float, wavelength: float, phase: float,
           rows: int = 24, cols: int = 48) -> trimesh.Trimesh:
    """An open, pleated vertical sheet (x across, z up, pleats along y), standing on z = 0."""
    x = np.linspace(-width / 2, width / 2, cols)
    z = np.linspace(0.0, height, rows)
    X, Z = np.meshgrid(x, z)
    Y = amplitude * np.sin(2 * math.pi * X / wavelength + phase) * (0.6 + 0.4 * Z / height)
    v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (i * cols + j).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + cols], 1), np.stack([a + 1, a + cols + 1, a + cols], 1)])
    return trimesh.Trimesh(v, faces, process=False)


@recipe("cloth")
def cloth(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """Cloth: one or two pleated curtain panels 1–2.6 m high reaching the floor (open sheets, as a capture
    sees them), or a folded towel or blanket, 2–5 layers lying flat (filled)."""
    colour = jitter(rng, pick(rng, FABRIC), 0.08)
    if rng.random() < 0.6:
        w, h = rng.uniform(0.5, 1.5), rng.uniform(1.0, 2.6)
        panels = int(rng.integers(1, 3))
        gap = rng.uniform(0.0, 0.8) if panels == 2 else 0.0
        sheets = []
        for k in range(panels):
            s = _sheet(w, h, rng.uniform(0.015, 0.06), rng.uniform(0.08, 0.25), rng.uniform(0, 2 * math.pi))
            s.apply_transform(trimesh.transformations.translation_matrix([(k - (panels - 1) / 2) * (w + gap), 0, 0]))
            sheets.append(s)
        return [Piece("fabric", concatenate(sheets), colour, 0.06)], _round(
            {"kind": "curtain", "width_m": w, "height_m": h, "panels": panels})
    length, width = rng.uniform(0.25, 0.7), rng.uniform(0.2, 0.5)
    layers = int(rng.integers(2, 6))
    t = rng.uniform(0.004, 0.02)
    slabs = [box(np.array([length * rng.uniform(0.97, 1.0), width * rng.uniform(0.97, 1.0), t]),
                 np.array([rng.uniform(-0.005, 0.005), rng.uniform(-0.005, 0.005), (k + 0.5) * t])) for k in range(layers)]
    return [Piece("fabric", concatenate(slabs), colour, 0.06, fill=True)], _round(
        {"kind": "folded", "size_m": [length, width, layers * t], "layers": layers})


def _bent_tube(length: float, radius: float, bend: float, taper: float, segments: int = 10) -> trimesh.Trimesh:
    """A closed tube of `length` (m) bent by `bend` radians over its length in the x-y plane, thickest
    (`radius`, m) in the middle and `taper` × as thick at the ends, lying on z = 0."""
    t = np.linspace(-0.5, 0.5, segments + 1)
    if bend > 1e-3:
        R = length / bend
        pts = np.stack([R * np.sin(t * bend), R * (1 - np.cos(t * bend)), np.zeros_like(t)], 1)
    else:
        pts = np.stack([t * length, np.zeros_like(t), np.zeros_like(t)], 1)
    rad = radius * (taper + (1 - taper) * np.cos(t * math.pi) ** 0.5)
    pts[:, 2] = rad  # the whole underside touches the ground
    return concatenate([tapered_segment(pts[k], pts[k + 1], rad[k], rad[k + 1], 12) for k in range(segments)])


@recipe("long_produce")
def long_produce(rng: np.random.Generator, parts: set) -> tuple[list[Piece], dict]:
    """1–4 long fruit or vegetables of one kind lying side by side: bananas (curved, tapered), cucumbers,
    carrots (a cone) or aubergines (filled)."""
    kind = pick(rng, list(PRODUCE))
    n = int(rng.integers(1, 5))
    pieces = []
    for k in range(n):
        colour = jitter(rng, pick(rng, PRODUCE[kind]), 0.06)
        if kind == "banana":
            m = _bent_tube(rng.uniform(0.15, 0.23), rng.uniform(0.015, 0.02), rng.uniform(0.6, 1.3), 0.35)
        elif kind == "cucumber":
            m = _bent_tube(rng.uniform(0.15, 0.3), rng.uniform(0.018, 0.03), rng.uniform(0.0, 0.3), 0.7)
        elif kind == "carrot":
            L, r = rng.uniform(0.12, 0.22), rng.uniform(0.012, 0.02)
            m = tapered_segment(np.array([-L / 2, 0, r]), np.array([L / 2, 0, r]), r, 0.002, 12)
        else:
            L, r = rng.uniform(0.14, 0.25), rng.uniform(0.03, 0.045)
            m = ellipsoid(np.array([0, 0, r]), np.array([L / 2, r, r]), 2)
        m.apply_transform(trimesh.transformations.translation_matrix([rng.uniform(-0.02, 0.02), k * 0.05, 0]))
        pieces.append(Piece("flesh", m, colour, 0.05, fill=True))
    return pieces, _round({"kind": kind, "pieces": n})
