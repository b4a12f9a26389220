"""Stiff parts: per part, true stiffness, a rigid body coupled to the MPM grid, or softened.

Why: an explicit MPM substep must not let the fastest elastic wave cross more than a fraction of
a cell, so a 7e10 Pa aluminium can needs tens of thousands of substeps per frame. When a part
needs more than `solver.max_substeps_per_frame`, `plan_stiff_parts` decides per part (by
`solver.stiff_parts`, docs/scene.md): "auto" (default) and "rigid" make a solid part (jelly or
metal) a rigid body — "auto" only when it would otherwise have to be softened more than
AUTO_SOFTEN_LIMIT×, milder cases are softened; "soften" lowers E until it fits (yield strain
kept); "true" never changes a material: it reports the substeps each part uses of the budget,
and refuses to run (InputError) when a part does not fit. Sand, snow, fluid and
visco-plastic parts are never made rigid (they flow): they are softened. Every choice is one
printed line, e.g. "part 3 (metal, 1,204 particles): E 7e+10 Pa needs 31,008 substeps/frame,
budget 2,000 → rigid".

A rigid body is coupled to the grid (`RigidBodies`) without being scattered into it (its
particles carry zero mass in P2G, so the grid holds only soft material). Each substep, after the
grid update, the body and the soft material on the grid nodes its particles cover take one
common rigid motion with their summed momentum and angular momentum (momentum in from the nodes
it covers: a perfectly inelastic, momentum-conserving exchange in which the body's full mass and
inertia answer every contact); those nodes then move with the body (velocity out: G2P hands the
rigid motion to the soft particles there). The body's particles get position c + R·r₀, velocity
v + ω×r, APIC matrix C = [ω]×, F = R and no stress, so relative distances inside a body are kept
to float precision and the Gaussians' covariances turn with it. Impulses given to its particles
reach the body as momentum; gravity and viscous damping act on it (wind and air drag do not).
Its particles that would pass the floor become heavy contact points in the same solve (the body
stops there with the torque that gives: landing on an edge, it tips), with Coulomb friction from
the contact push; the domain walls stop it as a whole. Fixed material holds it (held nodes are
heavy and at rest). Limits: two rigid bodies do not collide with each other; a body's state lives
in the solver, not in `State` (step() on other states does not move it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import InputError
from ..materials import JELLY, MATERIAL_NAMES, METAL
from .kernels import GridInfo, stencil_of
from .scene import STIFF_PART_MODES

AUTO_SOFTEN_LIMIT = 0.1  # "auto": a solid part that would need E × less than this becomes rigid
RIGID_MATERIALS = (JELLY, METAL)  # solids; the others flow and are softened instead
FAR = 1.0e30
FAR_F = wp.constant(FAR)  # the same, inside kernels
# a held grid node weighs this many times the body, and so do a body's floor contacts together: it
# (nearly) stops the motion there (all but 1/(1 + HEAVY) of the approach goes each substep). Not more:
# at 1e3 per contact point a 20°-tilted slab landing on an edge got tens of rad/s from the
# common-motion solve and diverged (the real pool capture's `drop`; tests/test_sim_rigid.py).
HEAVY = wp.constant(100.0)


@dataclass
class PartChoice:
    """What happened to one part that needed more substeps than the budget (in mode "true": to
    every moving part, reporting the budget it uses): label ("part 3", or "body" for particles without a part id), material
    name, particle count, largest E (Pa), substeps per frame it needs, the budget, the choice
    ("true", "rigid", "held" (rigid and touching fixed particles), "soften") and the factor
    applied to E (1 true, 0 rigid/held, < 1 softened)."""

    label: str
    material: str
    n_particles: int
    E_pa: float
    substeps_needed: int
    budget: int
    choice: str
    E_scale: float

    def need(self) -> str:
        """'part 3 (metal, 1,204 particles): E 7e+10 Pa needs 31,008 substeps/frame, budget 2,000'."""
        return (f"{self.label} ({self.material}, {self.n_particles:,} particles): E {self.E_pa:.3g} Pa needs "
                f"{self.substeps_needed:,} substeps/frame, budget {self.budget:,}")

    def line(self) -> str:
        """The printed line: need() + ' → rigid' (or the other choice)."""
        what = {"true": "true stiffness", "rigid": "rigid", "held": "rigid, held in place (touches fixed particles)",
                "soften": f"softened to {self.E_scale:.2g}×E"}[self.choice]
        return f"{self.need()} → {what}"


@dataclass
class StiffPlan:
    """plan_stiff_parts's answer, per particle in the caller's order: E_scale (N,) (0 for rigid
    and held particles), body (N,) int32 rigid-body index or −1, held (N,) bool (parts that touch
    fixed particles: held as a whole), and the per-part choices."""

    E_scale: np.ndarray
    body: np.ndarray
    held: np.ndarray
    choices: list[PartChoice]

    @property
    def n_bodies(self) -> int:
        return int(self.body.max()) + 1 if len(self.body) else 0


def substeps_needed(wave_speed_mps: np.ndarray, frame_dt_s: float, cfl: float, dx_m: float) -> np.ndarray:
    """Substeps per frame (int64 per particle) for a wave of speed c to cross ≤ cfl·dx per substep."""
    return np.ceil(frame_dt_s * np.asarray(wave_speed_mps, np.float64) / (cfl * dx_m) - 1e-9).astype(np.int64)


def plan_stiff_parts(mode: str, x: np.ndarray, part_id: np.ndarray, material_id: np.ndarray,
                     E_pa: np.ndarray, wave_speed_mps: np.ndarray, scale_now: np.ndarray, moving: np.ndarray,
                     fixed: np.ndarray, frame_dt_s: float, cfl: float, dx_m: float, budget: int,
                     origin: np.ndarray, allow_rigid: bool = True) -> StiffPlan:
    """Decide, per part, what to do with moving particles whose current wave speed
    (wave_speed·√scale_now) needs more than `budget` substeps per frame (see the module doc).

    Parts are split by part_id and then into pieces connected through occupied grid cells (two
    separate blocks with no part id are two bodies). `allow_rigid` False (bodies were already
    made earlier in the run) softens instead. Raises InputError in mode "true"."""
    if mode not in STIFF_PART_MODES:
        raise InputError(f"solver.stiff_parts must be one of {', '.join(STIFF_PART_MODES)}, got {mode!r}", "scene")
    n = len(x)
    c_now = np.asarray(wave_speed_mps, np.float64) * np.sqrt(scale_now)
    need = substeps_needed(c_now, frame_dt_s, cfl, dx_m)
    over = moving & (need > budget)
    c_allowed = cfl * dx_m * budget / frame_dt_s
    fit_scale = np.minimum(1.0, (c_allowed / np.maximum(np.asarray(wave_speed_mps, np.float64), 1e-30)) ** 2) * 0.999
    scale = np.asarray(scale_now, np.float64).copy()
    body = np.full(n, -1, np.int32)
    held = np.zeros(n, bool)
    choices: list[PartChoice] = []
    n_bodies = 0
    for pid in np.unique(part_id[over]):
        in_part = part_id == pid
        part_over = over & in_part
        mats = material_id[part_over]
        mat = int(np.bincount(mats).argmax())
        label = f"part {int(pid)}" if pid >= 0 else "body"
        choice = PartChoice(label, MATERIAL_NAMES[mat], int(part_over.sum()), float(E_pa[part_over].max()),
                            int(need[part_over].max()), int(budget), "soften", 1.0)
        if mode == "true":
            raise InputError(f"{choice.need()} but solver.stiff_parts is \"true\": raise "
                             f"solver.max_substeps_per_frame to {choice.substeps_needed} or choose \"rigid\"", "scene")
        solid = part_over & np.isin(material_id, RIGID_MATERIALS)
        too_soft_to_fit = fit_scale[part_over].min() < AUTO_SOFTEN_LIMIT
        rigid = allow_rigid and solid.any() and (mode == "rigid" or (mode == "auto" and too_soft_to_fit))
        if rigid:
            labels, touches_fixed = _pieces(x, solid, fixed & in_part, dx_m, origin)
            for k in range(1, int(labels.max()) + 1):
                piece = labels == k
                if touches_fixed[k]:
                    held |= piece
                else:
                    body[piece] = n_bodies
                    n_bodies += 1
            scale[solid] = 0.0
            choice.choice = "held" if held[solid].all() else "rigid"
            choice.E_scale = 0.0
            rest = part_over & ~solid  # flowing materials of the same part
        else:
            rest = part_over
        if rest.any():
            scale[rest] = np.minimum(scale[rest], fit_scale[rest])
            if not rigid:
                choice.E_scale = float(scale[rest].min())
        choices.append(choice)
    return StiffPlan(scale, body, held, choices)


def true_stiffness_report(part_id: np.ndarray, material_id: np.ndarray, E_pa: np.ndarray,
                          wave_speed_mps: np.ndarray, moving: np.ndarray, frame_dt_s: float, cfl: float, dx_m: float,
                          budget: int) -> list[PartChoice]:
    """Mode "true", every part within the budget: one PartChoice per moving part (stiffest first)
    saying how many substeps per frame its true stiffness needs, so the budget used is reported."""
    need = substeps_needed(wave_speed_mps, frame_dt_s, cfl, dx_m)
    out = []
    for pid in np.unique(part_id[moving]):
        sel = moving & (part_id == pid)
        mat = int(np.bincount(material_id[sel]).argmax())
        out.append(PartChoice(f"part {int(pid)}" if pid >= 0 else "body", MATERIAL_NAMES[mat], int(sel.sum()),
                              float(E_pa[sel].max()), int(need[sel].max()), int(budget), "true", 1.0))
    return sorted(out, key=lambda c: -c.substeps_needed)


def _pieces(x: np.ndarray, mask: np.ndarray, fixed: np.ndarray, dx_m: float,
            origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Label (N,) int (0 = not in mask, 1.. = piece) the particles of `mask` by connected occupied
    grid cells (26-neighbourhood), and say per piece whether a `fixed` particle shares or touches
    its cells (bool array indexed by label)."""
    from scipy import ndimage

    both = mask | fixed
    cells = np.floor((x[both] - origin) / dx_m).astype(np.int64)
    lo = cells.min(0)
    cells -= lo - 1
    occupied = np.zeros(cells.max(0) + 2, bool)
    occupied[tuple(cells.T)] = True
    labels_grid, _ = ndimage.label(occupied, structure=np.ones((3, 3, 3), bool))
    cell_label = labels_grid[tuple(cells.T)]
    labels = np.zeros(len(x), np.int64)
    labels[both] = cell_label
    labels[~mask] = 0
    # renumber the pieces that hold masked particles 1..K
    used = np.unique(labels[mask])
    remap = np.zeros(int(labels_grid.max()) + 1, np.int64)
    remap[used] = np.arange(1, len(used) + 1)
    touches = np.zeros(len(used) + 1, bool)
    fixed_labels = np.unique(labels_grid[tuple(cells[fixed[both]].T)]) if fixed.any() else np.zeros(0, np.int64)
    touches[remap[np.intersect1d(fixed_labels, used)]] = True
    return remap[labels], touches


# ---------------------------------------------------------------------------------------- kernels
@wp.func
def body_offset(rot: wp.quat, r0: wp.vec3):
    """r = R·r₀: a rigid particle's offset from its body's COM (one expression everywhere, so the
    velocity set by rigid_scatter and the one rigid_particles expects agree bit for bit)."""
    return wp.quat_to_matrix(rot) * r0


@wp.func
def contact_velocity(vel: wp.vec3, omega: wp.vec3, r: wp.vec3, gravity: wp.vec3, dt: float):
    """A rigid point's velocity this substep before any contact (m/s): v + ω×r + g·dt."""
    return vel + wp.cross(omega, r) + dt * gravity


@wp.func
def passes_floor(u: wp.vec3, z: float, floor: float, dt: float):
    """Whether a point at height z (m) moving at u would be below the floor after dt s."""
    return u[2] < 0.0 and z + dt * u[2] < floor


@wp.kernel
def rigid_count_contacts(x: wp.array(dtype=wp.vec3), order: wp.array(dtype=wp.int32),
                         body_of: wp.array(dtype=wp.int32), r0: wp.array(dtype=wp.vec3),
                         rot: wp.array(dtype=wp.quat), vel: wp.array(dtype=wp.vec3), omega: wp.array(dtype=wp.vec3),
                         floor: float, gravity: wp.vec3, dt: float, contacts: wp.array(dtype=float)):
    """Per body, the number of its particles that would pass the floor this substep (rigid_particles
    shares the floor's weight among them)."""
    p = wp.tid()
    idx = order[p]
    b = body_of[idx]
    if b < 0:
        return
    u = contact_velocity(vel[b], omega[b], body_offset(rot[b], r0[idx]), gravity, dt)
    if passes_floor(u, x[p][2], floor, dt):
        wp.atomic_add(contacts, b, 1.0)


@wp.kernel
def rigid_particles(v: wp.array(dtype=wp.vec3), x: wp.array(dtype=wp.vec3), order: wp.array(dtype=wp.int32),
                    body_of: wp.array(dtype=wp.int32), r0: wp.array(dtype=wp.vec3), mass: wp.array(dtype=float),
                    rot: wp.array(dtype=wp.quat), vel: wp.array(dtype=wp.vec3), omega: wp.array(dtype=wp.vec3),
                    grid: GridInfo, node_body: wp.array3d(dtype=wp.int32), kick: wp.array(dtype=wp.vec3),
                    kick_ang: wp.array(dtype=wp.vec3), lo: wp.array2d(dtype=float), hi: wp.array2d(dtype=float),
                    body_mass: wp.array(dtype=float), floor: float, gravity: wp.vec3, dt: float,
                    node_mass: wp.array(dtype=float), node_moment: wp.array(dtype=wp.vec3),
                    node_momentum: wp.array(dtype=wp.vec3), node_ang: wp.array(dtype=wp.vec3),
                    node_inertia: wp.array(dtype=wp.mat33), contacts: wp.array(dtype=float)):
    """Per rigid particle: tag the 27 grid nodes it covers with its body (id + 1); add any change
    of its velocity since the last rigid_scatter (an impulse) to its body as momentum m·Δv and
    angular momentum r×m·Δv; widen the body's extents. A particle that would pass the floor this
    substep becomes a contact point whose velocity keeps its sliding part and loses the part into the
    floor, summed with the covered nodes, so the common-motion solve stops the body there with the
    torque that gives (a body landing on a corner tips over). The contact points share HEAVY× the
    body's mass (`contacts`, counted by rigid_count_contacts): one corner weighs HEAVY×, a face of
    thousands of points no more in all, so the float32 sums of the solve do not cancel."""
    p = wp.tid()
    idx = order[p]
    b = body_of[idx]
    if b < 0:
        return
    xp = x[p]
    base, fx = stencil_of(xp, grid)
    for i in range(3):
        for j in range(3):
            for k in range(3):
                wp.atomic_max(node_body, base[0] + i, base[1] + j, base[2] + k, b + 1)
    r = body_offset(rot[b], r0[idx])
    dmv = mass[idx] * (v[p] - (vel[b] + wp.cross(omega[b], r)))
    if wp.length(dmv) > 0.0:
        wp.atomic_add(kick, b, dmv)
        wp.atomic_add(kick_ang, b, wp.cross(r, dmv))
    for d in range(3):
        wp.atomic_min(lo, b, d, xp[d])
        wp.atomic_max(hi, b, d, xp[d])
    u = contact_velocity(vel[b], omega[b], r, gravity, dt)  # this point's velocity this substep, before contact
    if passes_floor(u, xp[2], floor, dt):
        target = wp.vec3(u[0], u[1], wp.min((floor - xp[2]) / dt, 0.0))
        mh = HEAVY * body_mass[b] / wp.max(contacts[b], 1.0)
        wp.atomic_add(node_mass, b, mh)
        wp.atomic_add(node_moment, b, mh * r)
        wp.atomic_add(node_momentum, b, mh * target)
        wp.atomic_add(node_ang, b, mh * wp.cross(r, target))
        wp.atomic_add(node_inertia, b, mh * (wp.dot(r, r) * wp.identity(n=3, dtype=float) - wp.outer(r, r)))


@wp.kernel
def rigid_node_sums(node_body: wp.array3d(dtype=wp.int32), grid_mass: wp.array3d(dtype=float),
                    grid_fixed: wp.array3d(dtype=float), grid_velocity: wp.array3d(dtype=wp.vec3), grid: GridInfo,
                    box_lo: wp.vec3i, com: wp.array(dtype=wp.vec3), body_mass: wp.array(dtype=float),
                    node_mass: wp.array(dtype=float),
                    node_moment: wp.array(dtype=wp.vec3), node_momentum: wp.array(dtype=wp.vec3),
                    node_ang: wp.array(dtype=wp.vec3), node_inertia: wp.array(dtype=wp.mat33)):
    """Momentum in: per grid node a body covers that holds soft material, add the node's mass m,
    m·r, m·v, m·r×v and m(|r|²I − r rᵀ) to the body (r from the body's COM). A node held by fixed
    particles counts as resting and HEAVY× heavier than the body: the body sticks to
    fixed material as soft material does, instead of sinking into it."""
    a, bb, c = wp.tid()
    i = a + box_lo[0]
    j = bb + box_lo[1]
    k = c + box_lo[2]
    b = node_body[i, j, k] - 1
    m = grid_mass[i, j, k]
    if b < 0 or m <= 0.0:
        return
    r = grid.origin + wp.vec3(float(i), float(j), float(k)) * grid.dx - com[b]
    gv = grid_velocity[i, j, k]
    if grid_fixed[i, j, k] > 0.0:
        m = HEAVY * body_mass[b]
        gv = wp.vec3(0.0)
    wp.atomic_add(node_mass, b, m)
    wp.atomic_add(node_moment, b, m * r)
    wp.atomic_add(node_momentum, b, m * gv)
    wp.atomic_add(node_ang, b, m * wp.cross(r, gv))
    wp.atomic_add(node_inertia, b, m * (wp.dot(r, r) * wp.identity(n=3, dtype=float) - wp.outer(r, r)))


@wp.kernel
def rigid_solve(body_mass: wp.array(dtype=float), inertia0: wp.array(dtype=wp.mat33),
                inertia_inv0: wp.array(dtype=wp.mat33),
                kick: wp.array(dtype=wp.vec3), kick_ang: wp.array(dtype=wp.vec3), node_mass: wp.array(dtype=float),
                node_moment: wp.array(dtype=wp.vec3), node_momentum: wp.array(dtype=wp.vec3),
                node_ang: wp.array(dtype=wp.vec3), node_inertia: wp.array(dtype=wp.mat33),
                lo: wp.array2d(dtype=float), hi: wp.array2d(dtype=float), com: wp.array(dtype=wp.vec3),
                pivot: wp.array(dtype=wp.vec3), rot: wp.array(dtype=wp.quat), vel: wp.array(dtype=wp.vec3),
                omega: wp.array(dtype=wp.vec3), contacts: wp.array(dtype=float), gravity: wp.vec3, damping: float,
                wall_lo: wp.vec3, wall_hi: wp.vec3, friction: float, dt: float):
    """Per body: impulses, gravity and damping on (v, ω); then the body and the soft material on
    the nodes it covers take one common rigid motion (v', ω') with their summed momentum and
    angular momentum (a perfectly inelastic, momentum-conserving exchange: the body's full mass
    and inertia answer every contact); the floor and walls stop it as a whole (Coulomb friction
    on the floor); then advance COM and rotation (exact axis-angle step) and clear the sums."""
    b = wp.tid()
    R = wp.quat_to_matrix(rot[b])
    Ib = R * inertia0[b] * wp.transpose(R)
    M = body_mass[b]
    eye = wp.identity(n=3, dtype=float)
    Ib_inv = R * inertia_inv0[b] * wp.transpose(R)  # pseudo-inverse: no spin about an axis without extent
    v = vel[b] + kick[b] / M
    w = omega[b] + Ib_inv * kick_ang[b]
    decay = wp.exp(-damping * dt)
    v = (v + dt * gravity) * decay
    w = w * decay
    vz_free = v[2]
    if node_mass[b] > 0.0:  # soft material on the nodes it covers: one common rigid motion
        Mt = M + node_mass[b]
        S = node_moment[b]
        P = M * v + node_momentum[b]
        L = Ib * w + node_ang[b]
        A = Ib + node_inertia[b] + wp.skew(S) * wp.skew(S) / Mt  # inertia of both about their common COM
        # solved as (A/tr + 1e-7 I) w = rhs/tr: the same regularised solve, but a one-particle body
        # touching nodes that hold ~1e-11 kg has tr(A) ~ 1e-24 kg m², whose float32 determinant
        # (~tr³) underflows to 0 and made ω NaN (stop 53; then a NaN position indexed outside the grid)
        tr = A[0, 0] + A[1, 1] + A[2, 2]
        if tr > 0.0:
            w = wp.inverse(A / tr + 1.0e-7 * eye) * ((L - wp.cross(S, P) / Mt) / tr)
        else:  # no extent about the common COM: nothing to turn
            w = wp.vec3(0.0)
        v = (P - wp.cross(w, S)) / Mt
    dvn = float(0.0)
    if contacts[b] > 0.0:  # the floor pushed it up by this much: Coulomb friction below
        dvn = wp.max(v[2] - vz_free, 0.0)
    for d in range(3):
        # the fastest it may approach a wall: up to touching it, not at all once at or past it
        if v[d] < 0.0:
            new = wp.max(v[d], wp.min((wall_lo[d] - lo[b, d]) / dt, 0.0))
            if d == 2:
                dvn = dvn + new - v[d]
            v[d] = new
        if v[d] > 0.0:
            v[d] = wp.min(v[d], wp.max((wall_hi[d] - hi[b, d]) / dt, 0.0))
    if dvn > 0.0:  # floor contact: Coulomb friction on the sliding velocity
        vt = wp.vec3(v[0], v[1], 0.0)
        st = wp.length(vt)
        if st <= friction * dvn:
            v = wp.vec3(0.0, 0.0, v[2])
        else:
            v = v - vt * (friction * dvn / st)
    vel[b] = v
    omega[b] = w
    pivot[b] = com[b]
    com[b] = com[b] + dt * v
    angle = wp.length(w) * dt
    if angle > 0.0:
        rot[b] = wp.normalize(wp.quat_from_axis_angle(wp.normalize(w), angle) * rot[b])
    kick[b] = wp.vec3(0.0)
    kick_ang[b] = wp.vec3(0.0)
    node_mass[b] = 0.0
    node_moment[b] = wp.vec3(0.0)
    node_momentum[b] = wp.vec3(0.0)
    node_ang[b] = wp.vec3(0.0)
    node_inertia[b] = wp.mat33(0.0)
    contacts[b] = 0.0
    for d in range(3):
        lo[b, d] = FAR_F
        hi[b, d] = -FAR_F


@wp.kernel
def rigid_set_nodes(node_body: wp.array3d(dtype=wp.int32), grid_mass: wp.array3d(dtype=float),
                    grid_fixed: wp.array3d(dtype=float), grid_velocity: wp.array3d(dtype=wp.vec3), grid: GridInfo, box_lo: wp.vec3i,
                    pivot: wp.array(dtype=wp.vec3), vel: wp.array(dtype=wp.vec3), omega: wp.array(dtype=wp.vec3)):
    """Velocity out: nodes a body covers move with it (v' + ω'×r) — the soft material there
    sticks to the body, as it would to another MPM body; clears the node tags."""
    a, bb, c = wp.tid()
    i = a + box_lo[0]
    j = bb + box_lo[1]
    k = c + box_lo[2]
    b = node_body[i, j, k] - 1
    if b < 0:
        return
    node_body[i, j, k] = 0
    if grid_mass[i, j, k] > 0.0 and grid_fixed[i, j, k] <= 0.0:
        r = grid.origin + wp.vec3(float(i), float(j), float(k)) * grid.dx - pivot[b]
        grid_velocity[i, j, k] = vel[b] + wp.cross(omega[b], r)


@wp.kernel
def rigid_scatter(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                  F: wp.array(dtype=wp.mat33), stress: wp.array(dtype=wp.mat33), order: wp.array(dtype=wp.int32),
                  body_of: wp.array(dtype=wp.int32), r0: wp.array(dtype=wp.vec3), com: wp.array(dtype=wp.vec3),
                  rot: wp.array(dtype=wp.quat), vel: wp.array(dtype=wp.vec3), omega: wp.array(dtype=wp.vec3)):
    """Every rigid particle takes its body's motion (x = c + R r₀, v = v_b + ω×r, C = [ω]×,
    F = R, τ = 0), overwriting what G2P gave it."""
    p = wp.tid()
    idx = order[p]
    b = body_of[idx]
    if b < 0:
        return
    r = body_offset(rot[b], r0[idx])
    w = omega[b]
    x[p] = com[b] + r
    v[p] = vel[b] + wp.cross(w, r)
    C[p] = wp.skew(w)
    F[p] = wp.quat_to_matrix(rot[b])
    stress[p] = wp.mat33(0.0)


# ---------------------------------------------------------------------------------------- bodies
class RigidBodies:
    """B rigid bodies made of the particles with body[i] ≥ 0 (caller's order), coupled to the
    grid of an MPMSolver whose device mass array holds 0 for them (they are not scattered: the
    grid carries only soft material, and each body exchanges momentum with the nodes it covers).
    Per body on the device: mass (kg), body-frame inertia (kg m²), COM (m), orientation
    quaternion, v (m/s), ω (rad/s). Body frame = world frame at creation. Gravity and viscous
    damping act on the bodies; wind and air drag do not. Two rigid bodies do not collide with
    each other (a node covered by both belongs to one)."""

    def __init__(self, body: np.ndarray, x: np.ndarray, v: np.ndarray, mass: np.ndarray, dims: tuple[int, int, int],
                 gravity: tuple[float, float, float], damping: float, device: str) -> None:
        self.device = device
        self.n_bodies = int(body.max()) + 1
        self.gravity = wp.vec3(*gravity)
        self.damping = float(damping)
        B = self.n_bodies
        x64, v64, m64 = (np.asarray(a, np.float64) for a in (x, v, mass))
        sel = body >= 0
        b = body[sel]
        M = np.bincount(b, m64[sel], minlength=B)
        com = np.stack([np.bincount(b, m64[sel] * x64[sel, d], minlength=B) for d in range(3)], 1) / M[:, None]
        r = np.zeros_like(x64)
        r[sel] = x64[sel] - com[b]
        m_s = m64[sel]
        rr = r[sel]
        inertia = np.zeros((B, 3, 3))
        per = m_s[:, None, None] * (np.einsum("ij,ij->i", rr, rr)[:, None, None] * np.eye(3)
                                    - rr[:, :, None] * rr[:, None, :])
        np.add.at(inertia, b, per)
        P = np.stack([np.bincount(b, m_s * v64[sel, d], minlength=B) for d in range(3)], 1)
        L = np.zeros((B, 3))
        np.add.at(L, b, m_s[:, None] * np.cross(rr, v64[sel]))
        inv = np.linalg.pinv(inertia, rcond=1e-6, hermitian=True)  # no spin about an axis it has no extent along
        self.mass_kg = M
        self.inertia0 = inertia
        d = device
        self.body_of = wp.array(body.astype(np.int32), dtype=wp.int32, device=d)
        self.r0 = wp.array(r.astype(np.float32), dtype=wp.vec3, device=d)
        self.particle_mass = wp.array(m64.astype(np.float32), dtype=float, device=d)
        self.body_mass = wp.array(M.astype(np.float32), dtype=float, device=d)
        self.inertia0_wp = wp.array(inertia.astype(np.float32), dtype=wp.mat33, device=d)
        self.inertia_inv0 = wp.array(inv.astype(np.float32), dtype=wp.mat33, device=d)
        self.com = wp.array(com.astype(np.float32), dtype=wp.vec3, device=d)
        self.pivot = wp.array(com.astype(np.float32), dtype=wp.vec3, device=d)
        self.rot = wp.array(np.tile(np.array([0, 0, 0, 1], np.float32), (B, 1)), dtype=wp.quat, device=d)
        self.vel = wp.array((P / M[:, None]).astype(np.float32), dtype=wp.vec3, device=d)
        self.omega = wp.array(np.einsum("bij,bj->bi", inv, L).astype(np.float32), dtype=wp.vec3, device=d)
        self.kick = wp.zeros(B, dtype=wp.vec3, device=d)
        self.kick_ang = wp.zeros(B, dtype=wp.vec3, device=d)
        self.node_mass = wp.zeros(B, dtype=float, device=d)
        self.node_moment = wp.zeros(B, dtype=wp.vec3, device=d)
        self.node_momentum = wp.zeros(B, dtype=wp.vec3, device=d)
        self.node_ang = wp.zeros(B, dtype=wp.vec3, device=d)
        self.node_inertia = wp.zeros(B, dtype=wp.mat33, device=d)
        self.contacts = wp.zeros(B, dtype=float, device=d)  # points touching the floor this substep
        self.lo = wp.array(np.full((B, 3), FAR, np.float32), dtype=float, device=d)
        self.hi = wp.array(np.full((B, 3), -FAR, np.float32), dtype=float, device=d)
        self.node_body = wp.zeros(dims, dtype=wp.int32, device=d)
        self.grid_mass = wp.zeros(dims, dtype=float, device=d)  # the soft material's node masses, kept for advance()
        self.grid_fixed = wp.zeros(dims, dtype=float, device=d)  # > 0 where fixed particles hold a node

    def place(self, x: wp.array, v: wp.array, C: wp.array, F: wp.array, stress: wp.array, order: wp.array) -> None:
        """Give every rigid particle its body's motion (after creation, and after each G2P)."""
        wp.launch(rigid_scatter, dim=x.shape[0], device=self.device,
                  inputs=[x, v, C, F, stress, order, self.body_of, self.r0, self.com, self.rot, self.vel,
                          self.omega])

    def before_grid(self, x: wp.array, v: wp.array, order: wp.array, grid: GridInfo, grid_mass: wp.array,
                    grid_fixed: wp.array, floor_m: float, dt: float) -> None:
        """After P2G, before the grid update (which clears the node masses): tag the nodes the
        bodies cover, collect impulses given to rigid particles, keep the node masses and the
        held-node weights."""
        wp.launch(rigid_count_contacts, dim=x.shape[0], device=self.device,
                  inputs=[x, order, self.body_of, self.r0, self.rot, self.vel, self.omega, float(floor_m), self.gravity,
                          float(dt), self.contacts])
        wp.launch(rigid_particles, dim=x.shape[0], device=self.device,
                  inputs=[v, x, order, self.body_of, self.r0, self.particle_mass, self.rot, self.vel, self.omega, grid,
                          self.node_body, self.kick, self.kick_ang, self.lo, self.hi, self.body_mass, float(floor_m),
                          self.gravity, float(dt), self.node_mass, self.node_moment, self.node_momentum, self.node_ang,
                          self.node_inertia, self.contacts])
        wp.copy(self.grid_mass, grid_mass)
        wp.copy(self.grid_fixed, grid_fixed)

    def advance(self, grid: GridInfo, grid_velocity: wp.array, box_lo: tuple[int, int, int],
                box_shape: tuple[int, int, int], wall_lo: np.ndarray, wall_hi: np.ndarray, friction: float,
                dt: float) -> None:
        """After the grid update: momentum in from the covered nodes, one rigid step of dt s,
        velocity out to those nodes (G2P then carries it to the soft particles there)."""
        lo3 = wp.vec3i(*box_lo)
        wp.launch(rigid_node_sums, dim=box_shape, device=self.device,
                  inputs=[self.node_body, self.grid_mass, self.grid_fixed, grid_velocity, grid, lo3, self.com,
                          self.body_mass, self.node_mass,
                          self.node_moment, self.node_momentum, self.node_ang, self.node_inertia])
        wp.launch(rigid_solve, dim=self.n_bodies, device=self.device,
                  inputs=[self.body_mass, self.inertia0_wp, self.inertia_inv0, self.kick, self.kick_ang, self.node_mass, self.node_moment,
                          self.node_momentum, self.node_ang, self.node_inertia, self.lo, self.hi, self.com, self.pivot,
                          self.rot, self.vel, self.omega, self.contacts, self.gravity, self.damping, wp.vec3(*wall_lo),
                          wp.vec3(*wall_hi), float(friction), float(dt)])
        wp.launch(rigid_set_nodes, dim=box_shape, device=self.device,
                  inputs=[self.node_body, self.grid_mass, self.grid_fixed, grid_velocity, grid, lo3, self.pivot,
                          self.vel, self.omega])

    def state(self) -> dict[str, np.ndarray]:
        """Host copies: com (B,3) m, quaternion (B,4) x,y,z,w, v (B,3) m/s, omega (B,3) rad/s, mass (B,) kg."""
        return {"com": self.com.numpy().astype(np.float64), "quat": self.rot.numpy().astype(np.float64),
                "v": self.vel.numpy().astype(np.float64), "omega": self.omega.numpy().astype(np.float64),
                "mass": self.mass_kg.copy()}


def wall_bounds(origin: np.ndarray, dx_m: float, dims: tuple[int, int, int], boundary: int,
                ground_enabled: bool, ground_height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """World box (m) a rigid body's particles stay inside: the first and last free grid nodes of
    the domain, and the ground plane when there is one."""
    lo = np.asarray(origin, np.float64) + boundary * dx_m
    hi = np.asarray(origin, np.float64) + (np.asarray(dims) - 1 - boundary) * dx_m
    if ground_enabled:
        lo[2] = max(lo[2], ground_height_m)
    return lo, hi


__all__ = ["STIFF_PART_MODES", "AUTO_SOFTEN_LIMIT", "PartChoice", "StiffPlan", "RigidBodies", "plan_stiff_parts",
           "substeps_needed", "true_stiffness_report", "wall_bounds"]
