"""SplatCloud: the one container of 3D Gaussians that every pixie-gs stage reads and extends.

`read_splat` / `write_splat` are the entry points every command uses: they read any format in
pixie_gs.formats (INRIA 3DGS PLY, SuperSplat compressed PLY, antimatter15 .splat, Niantic .spz),
detected by content, and write by the output name (INRIA PLY unless it ends in .splat, .spz or
.compressed.ply). Every PLY vertex property is kept in its original order and bytes; properties
pixie-gs does not interpret (normals, features, ids…) travel verbatim in `extras`, and stages add
their results (e.g. `material_id`, `E`, `nu`, `density`) as further named per-Gaussian attributes.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError

SH_C0 = 0.28209479177387814  # degree-0 real spherical harmonic: rgb = 0.5 + SH_C0 · f_dc
MATERIAL_ATTRIBUTES = ("material_id", "E", "nu", "density")
LABEL_ATTRIBUTES = MATERIAL_ATTRIBUTES + ("part_id",)
_VALID_REST_COUNTS = {0: 0, 9: 1, 24: 2, 45: 3}
# Bounds of `SplatCloud.validate` beyond which a value is absurd, whatever the file's unit.
POSITION_LIMIT = 1e9  # |x|: beyond, float32 centres cannot resolve any Gaussian size
LOG_SCALE_LIMIT = 40.0  # |log σ|: σ² = exp(2 log σ) must stay a normal float32 (1e-35 … 5e34)
OPACITY_LOGIT_LIMIT = 1e6
SH_LIMIT = 1e6  # |f_dc|, |f_rest|: real splats stay within ±10; the SH energy must fit float32
FEATURE_LIMIT = 1e15  # extra float channels summed into the feature grid (float32 accumulators)
E_LIMIT_PA = 1e13  # Young's modulus: diamond is ~1.1e12 Pa
DENSITY_LIMIT_KG_M3 = 1e5  # osmium is 22 590 kg/m³  # number of f_rest properties -> SH degree
_CORE_GROUPS = {
    "means": ("x", "y", "z"),
    "log_scales": ("scale_0", "scale_1", "scale_2"),
    "rotations": ("rot_0", "rot_1", "rot_2", "rot_3"),
    "opacity_logits": ("opacity",),
    "sh_dc": ("f_dc_0", "f_dc_1", "f_dc_2"),
}


def quat_to_rotmat(quats_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices (N,3,3) from quaternions (N,4) in w,x,y,z order (normalised here)."""
    q = np.asarray(quats_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (N,4) w,x,y,z from proper rotation matrices (N,3,3) (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    n = len(R)
    q = np.empty((n, 4))
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    diag = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    k = np.argmax(diag, axis=1)
    for case in range(4):
        m = k == case
        if not m.any():
            continue
        r = R[m]
        if case == 0:
            s = np.sqrt(1.0 + tr[m]) * 2
            q[m] = np.stack([0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                             (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
        elif case == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2
            q[m] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                             (r[:, 0, 2] + r[:, 2, 0]) / s], axis=1)
        elif case == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2
            q[m] = np.stack([(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s,
                             (r[:, 1, 2] + r[:, 2, 1]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2
            q[m] = np.stack([(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                             (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s], axis=1)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@dataclass
class UnitCubeTransform:
    """Maps world coordinates into the unit cube: x_unit = (x_world − offset) · scale + 0.5.

    `scale` is isotropic (1 / longest side, with margin), so shapes and scale ratios survive.
    """

    scale: float
    offset: np.ndarray  # (3,) world-space centre of the bounding box

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        return ((np.asarray(x, dtype=np.float64) - self.offset) * self.scale + 0.5).astype(np.float32)

    def to_world(self, u: np.ndarray) -> np.ndarray:
        return ((np.asarray(u, dtype=np.float64) - 0.5) / self.scale + self.offset).astype(np.float32)


@dataclass
class SplatCloud:
    """N Gaussians: centres, log std-devs, rotations, opacity logits, SH colour and extras.

    `rotations` are kept exactly as stored (w,x,y,z, not always unit); `quats` gives them
    normalised. `sh_rest` keeps the file's f_rest order (channel-major: all R, then G, then B).
    `extras` holds every other per-Gaussian property in file order, with its dtype.
    """

    means: np.ndarray
    log_scales: np.ndarray
    rotations: np.ndarray
    opacity_logits: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    property_order: list[str] = field(default_factory=list)
    source: str | None = None
    source_format: str | None = None  # format it was read from (pixie_gs.formats.FORMATS), if read
    comments: list[str] = field(default_factory=list)  # PLY header comments (e.g. "pixie up 0 1 0"), kept on write

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        means: np.ndarray,
        log_scales: np.ndarray | None = None,
        rotations: np.ndarray | None = None,
        opacity_logits: np.ndarray | None = None,
        sh_dc: np.ndarray | None = None,
        sh_rest: np.ndarray | None = None,
        rgb: np.ndarray | None = None,
    ) -> "SplatCloud":
        """Build a cloud from arrays; missing fields get neutral defaults (identity rotation,
        std-dev 1 cm, opacity 0.9, grey or the given `rgb` in [0, 1])."""
        means = np.ascontiguousarray(means, dtype=np.float32).reshape(-1, 3)
        n = len(means)
        if log_scales is None:
            log_scales = np.full((n, 3), np.log(0.01), np.float32)
        if rotations is None:
            rotations = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
        if opacity_logits is None:
            opacity_logits = np.full(n, np.log(0.9 / 0.1), np.float32)
        if sh_dc is None:
            colour = np.full((n, 3), 0.5, np.float32) if rgb is None else np.asarray(rgb, np.float32)
            sh_dc = rgb_to_sh_dc(colour)
        if sh_rest is None:
            sh_rest = np.zeros((n, 0), np.float32)
        cloud = cls(
            means=means,
            log_scales=np.ascontiguousarray(log_scales, np.float32).reshape(n, 3),
            rotations=np.ascontiguousarray(rotations, np.float32).reshape(n, 4),
            opacity_logits=np.ascontiguousarray(opacity_logits, np.float32).reshape(n),
            sh_dc=np.ascontiguousarray(sh_dc, np.float32).reshape(n, 3),
            sh_rest=np.ascontiguousarray(sh_rest, np.float32).reshape(n, -1),
        )
        cloud.property_order = cloud._default_order()
        cloud.validate()
        return cloud

    def _default_order(self) -> list[str]:
        names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
        names += [f"f_rest_{i}" for i in range(self.sh_rest.shape[1])]
        names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
        return names + [k for k in self.extras]

    # ------------------------------------------------------------------ basic properties
    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return _VALID_REST_COUNTS[self.sh_rest.shape[1]]

    @property
    def quats(self) -> np.ndarray:
        """Unit quaternions (N,4) w,x,y,z (non-unit stored rotations normalised silently)."""
        q = self.rotations.astype(np.float64)
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)

    @property
    def scales(self) -> np.ndarray:
        """Standard deviations (N,3) in the cloud's length unit."""
        return np.exp(self.log_scales)

    @property
    def opacities(self) -> np.ndarray:
        """Opacity α in [0, 1] (sigmoid of the stored logit)."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits.astype(np.float64)))).astype(np.float32)

    def rgb(self) -> np.ndarray:
        """Base colour (N,3) in [0, 1] from the degree-0 SH coefficients."""
        return sh_dc_to_rgb(self.sh_dc)

    def rotation_matrices(self) -> np.ndarray:
        return quat_to_rotmat(self.rotations)

    def covariances(self) -> np.ndarray:
        """Covariance matrices Σ = R S Sᵀ Rᵀ (N,3,3), float64."""
        R = self.rotation_matrices()
        RS = R * np.exp(self.log_scales.astype(np.float64))[:, None, :]
        return RS @ RS.transpose(0, 2, 1)

    def set_covariances(self, cov: np.ndarray) -> None:
        """Replace scales and rotations by the eigen-decomposition of symmetric `cov` (N,3,3)."""
        cov = 0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).transpose(0, 2, 1))
        evals, evecs = np.linalg.eigh(cov)
        det = np.linalg.det(evecs)
        evecs[:, :, 2] *= np.where(det < 0, -1.0, 1.0)[:, None]
        self.log_scales = (0.5 * np.log(np.maximum(evals, 1e-30))).astype(np.float32)
        self.rotations = rotmat_to_quat(evecs).astype(np.float32)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min (3,), max (3,)) of the Gaussian centres."""
        return self.means.min(axis=0), self.means.max(axis=0)

    def unit_cube_transform(self, margin: float = 0.05) -> UnitCubeTransform:
        """Isotropic transform putting the centres into [margin, 1 − margin]³, centred."""
        lo, hi = self.bounds()
        extent = float(np.max(hi - lo))
        scale = (1.0 - 2.0 * margin) / extent if extent > 0 else 1.0
        return UnitCubeTransform(scale=scale, offset=((lo + hi) / 2.0).astype(np.float64))

    def normalized(self, margin: float = 0.05) -> tuple["SplatCloud", UnitCubeTransform]:
        """A copy scaled into the unit cube (sizes scaled too) and the transform that did it."""
        tf = self.unit_cube_transform(margin)
        out = self.copy()
        out.means = tf.to_unit(self.means)
        out.log_scales = (self.log_scales + np.float32(np.log(tf.scale))).astype(np.float32)
        return out, tf

    # ------------------------------------------------------------------ attributes
    def has(self, name: str) -> bool:
        return name in self.extras

    def get(self, name: str) -> np.ndarray:
        if name not in self.extras:
            raise InputError(f"has no per-Gaussian property '{name}'", self.source)
        return self.extras[name]

    def set(self, name: str, values: np.ndarray, dtype: np.dtype | type = np.float32) -> None:
        """Add or replace a per-Gaussian attribute (appended after the existing properties)."""
        arr = np.ascontiguousarray(values, dtype=dtype).reshape(-1)
        if len(arr) != len(self):
            raise ValueError(f"attribute {name!r} has {len(arr)} values for {len(self)} Gaussians")
        if name not in self.extras:
            self.property_order.append(name)
        self.extras[name] = arr

    def set_materials(self, material_id: np.ndarray, E_pa: np.ndarray, nu: np.ndarray,
                      density_kg_m3: np.ndarray) -> None:
        """Write the material attributes read by Pixie/PhysGaussian tools (id, E Pa, ν, ρ kg/m³)."""
        self.set("material_id", material_id, np.int32)
        self.set("E", E_pa, np.float32)
        self.set("nu", nu, np.float32)
        self.set("density", density_kg_m3, np.float32)

    def has_materials(self) -> bool:
        return all(name in self.extras for name in MATERIAL_ATTRIBUTES)

    def get_materials(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(material_id int32, E Pa, ν, ρ kg/m³); a clear error when the cloud has none."""
        missing = [n for n in MATERIAL_ATTRIBUTES if n not in self.extras]
        if missing:
            raise InputError(f"has no material attributes ({', '.join(missing)} missing); "
                             "run `pixie annotate` first", self.source)
        return (self.extras["material_id"].astype(np.int32), self.extras["E"].astype(np.float32),
                self.extras["nu"].astype(np.float32), self.extras["density"].astype(np.float32))

    # ------------------------------------------------------------------ copies and subsets
    def copy(self) -> "SplatCloud":
        return SplatCloud(
            means=self.means.copy(), log_scales=self.log_scales.copy(), rotations=self.rotations.copy(),
            opacity_logits=self.opacity_logits.copy(), sh_dc=self.sh_dc.copy(), sh_rest=self.sh_rest.copy(),
            extras={k: v.copy() for k, v in self.extras.items()}, property_order=list(self.property_order),
            source=self.source, source_format=self.source_format, comments=list(self.comments),
        )

    def subset(self, index: np.ndarray) -> "SplatCloud":
        """A new cloud with the Gaussians selected by a boolean mask or an index array."""
        return SplatCloud(
            means=self.means[index], log_scales=self.log_scales[index], rotations=self.rotations[index],
            opacity_logits=self.opacity_logits[index], sh_dc=self.sh_dc[index], sh_rest=self.sh_rest[index],
            extras={k: v[index] for k, v in self.extras.items()}, property_order=list(self.property_order),
            source=self.source, source_format=self.source_format, comments=list(self.comments),
        )

    def with_sh_degree(self, degree: int) -> "SplatCloud":
        """A copy with SH degree raised to `degree` by zero coefficients (the same colours from every
        view), e.g. to join a degree-0 object with a degree-3 one. Lowering a degree is refused: it
        would drop view-dependent colour."""
        if degree not in _VALID_REST_COUNTS.values():
            raise ValueError(f"SH degree must be 0-3 (got {degree})")
        if degree < self.sh_degree:
            raise ValueError(f"cannot lower SH degree {self.sh_degree} to {degree}")
        out = self.copy()
        if degree == self.sh_degree:
            return out
        old, new = self.sh_rest.shape[1] // 3, (degree + 1) ** 2 - 1  # coefficients per colour channel
        rest = np.zeros((len(self), 3, new), np.float32)
        rest[:, :, :old] = self.sh_rest.reshape(len(self), 3, old)  # channel-major: all R, then G, then B
        out.sh_rest = rest.reshape(len(self), 3 * new)
        order = [name for name in out.property_order if not name.startswith("f_rest_")]
        at = order.index("f_dc_2") + 1 if "f_dc_2" in order else len(order)
        order[at:at] = [f"f_rest_{i}" for i in range(3 * new)]
        out.property_order = order
        return out

    @staticmethod
    def concatenate(clouds: list["SplatCloud"]) -> "SplatCloud":
        """Join clouds with the same SH degree; extras present in every cloud are kept."""
        if not clouds:
            raise ValueError("nothing to concatenate")
        degrees = {c.sh_rest.shape[1] for c in clouds}
        if len(degrees) != 1:
            raise ValueError("clouds have different SH degrees")
        common = [k for k in clouds[0].extras if all(k in c.extras for c in clouds)]
        out = SplatCloud(
            means=np.concatenate([c.means for c in clouds]),
            log_scales=np.concatenate([c.log_scales for c in clouds]),
            rotations=np.concatenate([c.rotations for c in clouds]),
            opacity_logits=np.concatenate([c.opacity_logits for c in clouds]),
            sh_dc=np.concatenate([c.sh_dc for c in clouds]),
            sh_rest=np.concatenate([c.sh_rest for c in clouds]),
            extras={k: np.concatenate([c.extras[k] for c in clouds]) for k in common},
        )
        out.property_order = [p for p in clouds[0].property_order if p in common or not _is_extra(p)]
        out.comments = list(clouds[0].comments)
        return out

    # ------------------------------------------------------------------ validation
    @np.errstate(all="ignore")  # it looks for NaN, inf and absurd values: numpy's warnings about them add nothing
    def invalid_gaussians(self) -> list[tuple[str, np.ndarray]]:
        """(problem, bad mask (N,)) for every checked property with at least one bad Gaussian.

        Checked: positions (finite, |x| ≤ 1e9, no subnormals), log scales (finite, |log σ| ≤ 40 so
        σ² stays a normal float32), rotations (finite, non-zero), opacity, f_dc, f_rest (finite,
        |c| ≤ 1e6), float extras the feature grid reads (finite, ≤ 1e15) and, when present, the
        material attributes (known material_id, 0 < E ≤ 1e13 Pa, 0 ≤ ν < 0.5, 0 < ρ ≤ 1e5 kg/m³).
        """
        from .field import extra_feature_names
        from .materials import BACKGROUND, MATERIAL_NAMES

        found: list[tuple[str, np.ndarray]] = []

        def check(name: str, arr: np.ndarray, limit: float, extra_bad: np.ndarray | None = None,
                  range_text: str | None = None) -> None:
            a = np.asarray(arr, np.float64).reshape(len(arr), -1)
            nonfinite = ~np.isfinite(a).all(axis=1)
            absurd = (np.abs(a) > limit).any(axis=1)
            if extra_bad is not None:
                absurd |= extra_bad
            if nonfinite.any():
                found.append((f"non-finite {name} (NaN/inf)", nonfinite | absurd))
            elif absurd.any():
                found.append((f"out-of-range {name} ({range_text or f'|value| > {limit:g}'})", absurd))

        pos = np.asarray(self.means, np.float64).reshape(len(self.means), -1)
        subnormal = ((pos != 0) & (np.abs(pos) < np.finfo(np.float32).tiny)).any(axis=1)
        check("position", self.means, POSITION_LIMIT, subnormal, f"|x| > {POSITION_LIMIT:g} or subnormal")
        check("scale", self.log_scales, LOG_SCALE_LIMIT, None, f"|log σ| > {LOG_SCALE_LIMIT:g}")
        q = np.asarray(self.rotations, np.float64).reshape(len(self.rotations), -1)
        zero = ~(np.linalg.norm(q, axis=1) > 1e-12)
        if (zero | ~np.isfinite(q).all(axis=1)).any():
            found.append(("zero-length or non-finite rotation quaternion", zero | ~np.isfinite(q).all(axis=1)))
        check("opacity", self.opacity_logits, OPACITY_LOGIT_LIMIT)
        check("f_dc", self.sh_dc, SH_LIMIT)
        if self.sh_rest.shape[1]:
            check("f_rest", self.sh_rest, SH_LIMIT)
        for name in extra_feature_names(self):
            check(name, self.extras[name], FEATURE_LIMIT)
        if "material_id" in self.extras:
            known = [k for k in MATERIAL_NAMES if k != BACKGROUND]
            bad = ~np.isin(np.asarray(self.extras["material_id"], np.float64), np.array(known, np.float64))
            if bad.any():
                found.append((f"unknown material_id (known: {', '.join(map(str, known))})", bad))
        ranges = {"E": (False, E_LIMIT_PA, "0 < E ≤ 1e13 Pa"), "nu": (True, 0.5, "0 ≤ nu < 0.5"),
                  "density": (False, DENSITY_LIMIT_KG_M3, "0 < density ≤ 1e5 kg/m³")}
        for name, (zero_ok, hi, text) in ranges.items():
            if name in self.extras:
                v = np.asarray(self.extras[name], np.float64)
                outside = ((v < 0) if zero_ok else (v <= 0)) | ((v >= hi) if name == "nu" else (v > hi))
                check(name, v, np.inf, outside, text)
        return found

    def validate(self) -> None:
        """Raise InvalidGaussiansError (an InputError naming the file, the property, how many
        Gaussians and the first index) for any NaN/inf/absurd value; InputError when empty."""
        src = self.source or "<splat>"
        if len(self.means) == 0:
            raise InputError("has zero vertices", src)
        problems = self.invalid_gaussians()
        if problems:
            name, bad = problems[0]
            mask = np.zeros(len(self), bool)
            for _, b in problems:
                mask |= b
            more = f"; {len(problems) - 1} more properties are bad too" if len(problems) > 1 else ""
            raise InvalidGaussiansError(
                f"{name} in {int(bad.sum())} of {len(self)} Gaussians, first at vertex {int(np.argmax(bad))}"
                f"{more} ({int(mask.sum())} Gaussians in all; fix the file or pass --drop-invalid to remove them)",
                src, cloud=self, mask=mask)

    # ------------------------------------------------------------------ I/O
    @classmethod
    def read(cls, path: str | Path) -> "SplatCloud":
        return read_splat(path)

    def write(self, path: str | Path) -> None:
        write_splat(self, path)


class InvalidGaussiansError(InputError):
    """Some Gaussians of a cloud hold NaN/inf/absurd values; `cloud` and `mask` (N,) say which,
    so a caller asked to (`--drop-invalid`) can remove them instead of failing."""

    def __init__(self, message: str, path: str | Path | None, cloud: "SplatCloud", mask: np.ndarray) -> None:
        super().__init__(message, path)
        self.cloud = cloud
        self.mask = mask


def read_splat_valid(path: str | Path, drop_invalid: bool = False) -> SplatCloud:
    """`read_splat(path)`; with `drop_invalid`, Gaussians with invalid values are removed (and
    how many is said on stderr) instead of failing. All of them invalid is still an error."""
    import sys

    try:
        return read_splat(path)
    except InvalidGaussiansError as exc:
        if not drop_invalid:
            raise
        kept = exc.cloud.subset(~exc.mask)
        if len(kept) == 0:
            raise InputError(f"every one of its {len(exc.mask)} Gaussians has invalid values; "
                             "nothing left after --drop-invalid", path) from None
        names = ", ".join(name for name, _ in exc.cloud.invalid_gaussians())
        print(f"[pixie] {path}: dropped {int(exc.mask.sum())} of {len(exc.mask)} Gaussians with invalid "
              f"values ({names}); {len(kept)} kept", file=sys.stderr, flush=True)
        kept.validate()
        if kept.source_format is None:
            from .formats import detect_format

            kept.source_format = detect_format(path)
        return kept


def sh_dc_to_rgb(sh_dc: np.ndarray) -> np.ndarray:
    """Base colour (M,3) float32 in [0, 1] of degree-0 SH coefficients (M,3) (the inverse of rgb_to_sh_dc,
    clipped): for a subset of Gaussians without computing every colour first."""
    return np.clip(0.5 + SH_C0 * sh_dc, 0.0, 1.0).astype(np.float32)


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """Degree-0 SH coefficients that reproduce base colour `rgb` in [0, 1]."""
    return ((np.asarray(rgb, dtype=np.float32) - 0.5) / SH_C0).astype(np.float32)


def _is_extra(name: str) -> bool:
    core = {p for group in _CORE_GROUPS.values() for p in group}
    return name not in core and not name.startswith("f_rest_")


def read_splat(path: str | Path) -> SplatCloud:
    """Read a splat in any supported format (detected by content) into a validated SplatCloud.

    Raises InputError (file name + problem, one line) for anything that is not a usable splat;
    `cloud.source_format` records the format found.
    """
    from .formats import read_any

    with np.errstate(all="ignore"):  # a damaged file's NaN/inf/overflow is refused by validation, in one line
        return read_any(path)


def _rest_index(name: str) -> int:
    m = re.fullmatch(r"f_rest_(\d+)", name)
    return int(m.group(1)) if m else -1


def to_structured(cloud: SplatCloud) -> np.ndarray:
    """The vertex table as a little-endian structured array in the cloud's property order."""
    from .formats.inria_ply import to_structured as _to_structured

    return _to_structured(cloud)


def write_splat(cloud: SplatCloud, path: str | Path, fmt: str | None = None) -> None:
    """Write `cloud` atomically (temp file + rename): binary little-endian 3DGS `.ply` unless the
    name ends in .splat, .spz or .compressed.ply (or `fmt` names a format of pixie_gs.formats)."""
    from .formats import format_for_path, lossy_note, normalise_format, write_any
    from .progress import stage

    target = normalise_format(fmt) if fmt else format_for_path(path)
    note = lossy_note(cloud, target)
    if note and cloud.extras:  # a command's output named .splat/.spz/.compressed.ply loses its attributes
        stage(f"{path}: lossy: {note}")
    write_any(cloud, path, target)
