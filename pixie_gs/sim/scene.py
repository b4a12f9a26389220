"""Scene: everything around the object that a simulation needs (forces, boundaries, solver knobs).

Loaded from one JSON file (every key documented in docs/scene.md) or a named preset from
pixie_gs/data/scenes/. World units: metres, seconds, kg, Pa; world z points up.
Unknown keys and bad values raise a one-line InputError naming the file and the key.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError, require_file

BOUNDARY_CELLS = 3  # grid nodes this close to the domain faces act as walls (B-spline support)
PRESETS = ("drop", "wind", "push")
UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
Vec3 = tuple[float, float, float]
STIFF_PART_MODES = ("auto", "rigid", "soften", "true")  # solver.stiff_parts (sim/rigid.py), default first
MAX_SCENE_BYTES = 10_000_000  # a scene file is a few kB; refuse anything absurd before parsing
MAX_MAGNITUDE = 1e12  # any number of a scene (m, s, m/s, Pa, …): beyond, float32 physics is meaningless
MAX_SIZE_M = 1e4  # domain and object sides (m)
MIN_SIZE_M = 1e-3  # domain and object sides (m): below a millimetre the grid spacing loses meaning (a 5e-324 m side made it 0)
MAX_GRID = 4096  # grid cells along the longest side
GRID_BYTES_PER_NODE = 32  # solver arrays per grid node: mass, momentum, fixed, velocity (float32)


def _finite_number(value: Any) -> bool:
    """A JSON number (not a bool) that is finite and within ±MAX_MAGNITUDE (huge ints included)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value)) and abs(float(value)) <= MAX_MAGNITUDE
    except OverflowError:
        return False


def _show(value: Any, limit: int = 60) -> str:
    """A short JSON rendering of a bad value for an error message (never thousands of digits)."""
    try:
        text = json.dumps(value)
    except (ValueError, TypeError, RecursionError):
        text = type(value).__name__
    return text if len(text) <= limit else text[:limit] + "…"


@dataclass
class Region:
    """Axis-aligned box in world coordinates (m): min corner, max corner."""

    min: Vec3
    max: Vec3

    def contains(self, x: np.ndarray) -> np.ndarray:
        """Mask (N,) of points x (N,3) inside the box (faces included)."""
        x = np.asarray(x)
        return np.all((x >= np.asarray(self.min)) & (x <= np.asarray(self.max)), axis=1)


@dataclass
class ObjectPlacement:
    """size_m: longest side of the object (m); position: world point of its bottom centre (m)."""

    size_m: float = 0.5
    position: Vec3 = (0.0, 0.0, 0.0)


@dataclass
class Domain:
    """Simulation box: size_m (cube side, or [x, y, z]) m, grid = cells along the longest side,
    origin = world min corner (m; None = centred on the object, floor 3 cells below the ground)."""

    size_m: float | Vec3 = 1.0
    grid: int = 64
    origin: Vec3 | None = None


@dataclass
class Ground:
    """Horizontal plane z = height_m (m) with Coulomb friction coefficient μ = friction."""

    enabled: bool = True
    height_m: float = 0.0
    friction: float = 0.5


@dataclass
class Wind:
    """Body acceleration (m/s²) in `region` (None = everywhere) for start_s ≤ t < end_s (None = ∞),
    scaled by (1 + gust_amplitude · sin(2π · gust_frequency_hz · t))."""

    acceleration: Vec3 = (0.0, 0.0, 0.0)
    region: Region | None = None
    start_s: float = 0.0
    end_s: float | None = None
    gust_amplitude: float = 0.0
    gust_frequency_hz: float = 0.0


@dataclass
class Impulse:
    """At time_s (s), add velocity_change (m/s) to every particle in `region` (None = all)."""

    time_s: float = 0.0
    velocity_change: Vec3 = (0.0, 0.0, 0.0)
    region: Region | None = None


@dataclass
class FixedSpec:
    """Particles held in place: those inside `region` at the start and/or with a part_id listed."""

    region: Region | None = None
    part_ids: list[int] = field(default_factory=list)


@dataclass
class PartOverride:
    """Per-part changes applied when building particles (by sim-io): E·E_scale, ρ·density_scale,
    yield stress (Pa, None = unchanged), fixed (hold the part in place)."""

    E_scale: float = 1.0
    density_scale: float = 1.0
    yield_stress_pa: float | None = None
    fixed: bool = False


@dataclass
class SolverSettings:
    """cfl: fraction of a cell the fastest elastic wave crosses per substep (0.3–0.5 is stable);
    velocity_cfl: fraction of a cell the fastest particle moves per substep;
    max_substeps_per_frame: the substep budget; a part needing more is handled per part by
    stiff_parts (each choice printed, sim/rigid.py): "auto" (a solid part that would have to be
    softened more than 10× becomes a rigid body coupled to the grid, milder cases are softened),
    "rigid" (every solid part over budget is rigid), "soften" (E lowered to fit, yield strain
    kept), "true" (never change a material: an error names the substeps needed);
    particles_per_cell: interior filling density used by sim-io."""

    cfl: float = 0.4
    velocity_cfl: float = 0.25
    max_substeps_per_frame: int = 2000
    particles_per_cell: int = 8
    stiff_parts: str = "auto"


@dataclass
class MaterialSettings:
    """Parameters of the constitutive models that the per-particle file attributes do not carry."""

    sand_friction_angle_deg: float = 25.0  # reproduces the Lube/Lajeunesse runout law (benchmarks)
    snow_critical_compression: float = 2.5e-2  # θc (Stomakhin et al. 2013)
    snow_critical_stretch: float = 7.5e-3  # θs
    snow_hardening: float = 10.0  # ξ
    metal_yield_strain: float = 1e-3  # σ_y = strain · E when the particle has no yield_stress
    viscoplastic_yield_strain: float = 1e-3  # same, for visco-plastic (id 3)
    viscoplastic_viscosity_pa_s: float = 10.0  # η of the Perzyna-type plastic flow (id 3)
    fluid_viscosity_pa_s: float = 0.0  # dynamic viscosity of fluid (id 4); 0 = inviscid


@dataclass
class Scene:
    """The world around the object. See docs/scene.md for every key, unit and default."""

    up: str = "z"
    object: ObjectPlacement = field(default_factory=ObjectPlacement)
    domain: Domain = field(default_factory=Domain)
    gravity: Vec3 = (0.0, 0.0, -9.81)
    ground: Ground = field(default_factory=Ground)
    walls: str = "slip"
    damping: float = 0.0
    air_drag: float = 0.0
    wind: list[Wind] = field(default_factory=list)
    impulses: list[Impulse] = field(default_factory=list)
    fixed: list[FixedSpec] = field(default_factory=list)
    part_overrides: dict[int, PartOverride] = field(default_factory=dict)
    solver: SolverSettings = field(default_factory=SolverSettings)
    materials: MaterialSettings = field(default_factory=MaterialSettings)

    # ------------------------------------------------------------------ grid geometry
    @property
    def domain_size(self) -> np.ndarray:
        """Domain extent (3,) m."""
        return np.broadcast_to(np.asarray(self.domain.size_m, dtype=np.float64), (3,)).copy()

    @property
    def dx(self) -> float:
        """Grid spacing (m): longest domain side / domain.grid."""
        return float(self.domain_size.max() / self.domain.grid)

    @property
    def grid_dims(self) -> tuple[int, int, int]:
        """Number of grid nodes along x, y, z (cells + 1)."""
        cells = np.maximum(np.round(self.domain_size / self.dx).astype(int), 2 * BOUNDARY_CELLS + 1)
        return tuple(int(c) + 1 for c in cells)  # type: ignore[return-value]

    def domain_origin(self) -> np.ndarray:
        """World position (3,) m of the domain's min corner (explicit, or placed around the object)."""
        if self.domain.origin is not None:
            return np.asarray(self.domain.origin, dtype=np.float64)
        size = self.domain_size
        pos = np.asarray(self.object.position, dtype=np.float64)
        origin = pos - 0.5 * size
        if self.ground.enabled:
            origin[2] = self.ground.height_m - BOUNDARY_CELLS * self.dx
        else:
            origin[2] = pos[2] + 0.5 * self.object.size_m - 0.5 * size[2]
        return origin

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str | Path | None = None) -> "Scene":
        """Build a Scene from a JSON-like dict; missing keys take their defaults."""
        return _SceneParser(source).scene(data)

    @classmethod
    def from_json(cls, path: str | Path) -> "Scene":
        """Load a scene JSON file (one-line InputError naming the file for any problem)."""
        path = Path(path)
        if path.exists():  # refuse FIFOs/devices (reading one would block); missing → read error below
            require_file(path, "a scene JSON file")
        if path.is_file() and path.stat().st_size > MAX_SCENE_BYTES:
            raise InputError(f"is {path.stat().st_size} bytes; a scene JSON is at most {MAX_SCENE_BYTES}", path)
        try:
            text = path.read_bytes().decode("utf-8")
        except OSError as exc:
            raise InputError(f"cannot read scene file ({exc.strerror or exc})", path) from None
        except UnicodeDecodeError as exc:
            raise InputError(f"not UTF-8 text (byte {exc.start}); a scene is a JSON file", path) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON (line {exc.lineno}: {exc.msg})", path) from None
        except RecursionError:
            raise InputError("JSON nested too deeply", path) from None
        except ValueError as exc:  # e.g. an integer literal with thousands of digits
            raise InputError(f"not usable JSON ({str(exc).splitlines()[0][:100]})", path) from None
        return cls.from_dict(data, source=path)

    @classmethod
    def preset(cls, name: str) -> "Scene":
        """One of the shipped scenes: 'drop', 'wind', 'push' (pixie_gs/data/scenes/NAME.json)."""
        if name not in PRESETS:
            raise InputError(f"unknown scene preset '{name}' (choose from {', '.join(PRESETS)})")
        res = resources.files("pixie_gs") / "data" / "scenes" / f"{name}.json"
        with resources.as_file(res) as p:
            return cls.from_json(p)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict with every key (defaults included)."""
        def region(r: Region | None) -> dict[str, list[float]] | None:
            return None if r is None else {"min": list(r.min), "max": list(r.max)}

        size = self.domain.size_m
        return {
            "up": self.up,
            "object": {"size_m": self.object.size_m, "position": list(self.object.position)},
            "domain": {"size_m": size if isinstance(size, (int, float)) else list(size),
                       "grid": self.domain.grid,
                       "origin": None if self.domain.origin is None else list(self.domain.origin)},
            "gravity": list(self.gravity),
            "ground": {"enabled": self.ground.enabled, "height_m": self.ground.height_m,
                       "friction": self.ground.friction},
            "walls": self.walls,
            "damping": self.damping,
            "air_drag": self.air_drag,
            "wind": [{"acceleration": list(w.acceleration), "region": region(w.region),
                      "start_s": w.start_s, "end_s": w.end_s, "gust_amplitude": w.gust_amplitude,
                      "gust_frequency_hz": w.gust_frequency_hz} for w in self.wind],
            "impulses": [{"time_s": i.time_s, "velocity_change": list(i.velocity_change),
                          "region": region(i.region)} for i in self.impulses],
            "fixed": [{"region": region(f.region), "part_ids": list(f.part_ids)} for f in self.fixed],
            "part_overrides": {str(k): {"E_scale": o.E_scale, "density_scale": o.density_scale,
                                        "yield_stress_pa": o.yield_stress_pa, "fixed": o.fixed}
                               for k, o in self.part_overrides.items()},
            "solver": dict(vars(self.solver)),
            "materials": dict(vars(self.materials)),
        }

    def to_json(self, path: str | Path) -> None:
        """Write the scene as JSON (atomically)."""
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")


class _SceneParser:
    """Checks a JSON dict key by key, raising InputError('key X: problem', file)."""

    def __init__(self, source: str | Path | None) -> None:
        self.source = str(source) if source is not None else "scene"

    def fail(self, key: str, problem: str) -> InputError:
        key = "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in key)  # one line, whatever the key
        key = key if len(key) <= 80 else key[:80] + "…"
        return InputError(f"key '{key}': {problem}", self.source)

    def table(self, d: Any, key: str, allowed: tuple[str, ...]) -> dict[str, Any]:
        if not isinstance(d, dict):
            raise self.fail(key or "(top level)", "must be a JSON object")
        unknown = sorted(set(d) - set(allowed))
        if unknown:
            name = f"{key}.{unknown[0]}" if key else unknown[0]
            raise self.fail(name, f"unknown key (allowed: {', '.join(allowed)})")
        return d

    def number(self, d: dict, name: str, key: str, default: float | None, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, allow_none: bool = False) -> Any:
        value = d.get(name, default)
        full = f"{key}.{name}" if key else name
        if value is None and (allow_none or default is None and name not in d):
            return None
        if not _finite_number(value):
            raise self.fail(full, f"must be a finite number (|x| ≤ {MAX_MAGNITUDE:g}), got {_show(value)}")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            raise self.fail(full, f"must be {'>' if lo_open else '≥'} {lo:g}, got {value:g}")
        if hi is not None and value > hi:
            raise self.fail(full, f"must be ≤ {hi:g}, got {value:g}")
        return float(value)

    def integer(self, d: dict, name: str, key: str, default: int, lo: int, hi: int | None = None) -> int:
        value = d.get(name, default)
        full = f"{key}.{name}" if key else name
        if isinstance(value, bool) or not isinstance(value, int) or value < lo or (hi is not None and value > hi):
            limits = f"≥ {lo}" + ("" if hi is None else f" and ≤ {hi}")
            raise self.fail(full, f"must be an integer {limits}, got {_show(value)}")
        return int(value)

    def boolean(self, d: dict, name: str, key: str, default: bool) -> bool:
        value = d.get(name, default)
        if not isinstance(value, bool):
            raise self.fail(f"{key}.{name}" if key else name, f"must be true or false, got {_show(value)}")
        return value

    def choice(self, d: dict, name: str, key: str, allowed: tuple[str, ...]) -> str:
        """One of `allowed` (the first is the default)."""
        value = d.get(name, allowed[0])
        if value not in allowed:
            raise self.fail(f"{key}.{name}", f"must be one of {', '.join(allowed)}, got {_show(value)}")
        return value

    def vec3(self, value: Any, key: str) -> Vec3:
        if not isinstance(value, list) or len(value) != 3 or not all(_finite_number(v) for v in value):
            raise self.fail(key, f"must be a list of 3 finite numbers (|x| ≤ {MAX_MAGNITUDE:g}), got {_show(value)}")
        return (float(value[0]), float(value[1]), float(value[2]))

    def region(self, value: Any, key: str) -> Region | None:
        if value is None:
            return None
        d = self.table(value, key, ("min", "max"))
        if "min" not in d or "max" not in d:
            raise self.fail(key, "a region needs both 'min' and 'max' (world metres)")
        lo, hi = self.vec3(d["min"], f"{key}.min"), self.vec3(d["max"], f"{key}.max")
        if any(a > b for a, b in zip(lo, hi)):
            raise self.fail(key, "region 'min' must be ≤ 'max' on every axis")
        return Region(lo, hi)

    def items(self, d: dict, name: str) -> list[Any]:
        value = d.get(name, [])
        if not isinstance(value, list):
            raise self.fail(name, "must be a list")
        return value

    def scene(self, data: Any) -> Scene:
        d = self.table(data, "", tuple(Scene.__dataclass_fields__))
        up = d.get("up", "z")
        if up not in UP_AXES:
            raise self.fail("up", f"must be one of {', '.join(UP_AXES)}, got {_show(up)}")
        o = self.table(d.get("object", {}), "object", ("size_m", "position"))
        placement = ObjectPlacement(self.number(o, "size_m", "object", 0.5, lo=MIN_SIZE_M, hi=MAX_SIZE_M),
                                    self.vec3(o.get("position", [0, 0, 0]), "object.position"))
        dm = self.table(d.get("domain", {}), "domain", ("size_m", "grid", "origin"))
        size = dm.get("size_m", 1.0)
        if isinstance(size, list):
            size = self.vec3(size, "domain.size_m")
            if min(size) < MIN_SIZE_M or max(size) > MAX_SIZE_M:
                raise self.fail("domain.size_m", f"every side must be ≥ {MIN_SIZE_M:g} m and ≤ {MAX_SIZE_M:g} m")
        else:
            size = self.number(dm, "size_m", "domain", 1.0, lo=MIN_SIZE_M, hi=MAX_SIZE_M)
        origin = dm.get("origin")
        domain = Domain(size, self.integer(dm, "grid", "domain", 64, lo=8, hi=MAX_GRID),
                        None if origin is None else self.vec3(origin, "domain.origin"))
        self.check_grid_memory(Scene(domain=domain))
        g = self.table(d.get("ground", {}), "ground", ("enabled", "height_m", "friction"))
        ground = Ground(self.boolean(g, "enabled", "ground", True),
                        self.number(g, "height_m", "ground", 0.0),
                        self.number(g, "friction", "ground", 0.5, lo=0.0))
        walls = d.get("walls", "slip")
        if walls not in ("slip", "sticky"):
            raise self.fail("walls", f"must be \"slip\" or \"sticky\", got {_show(walls)}")
        scene = Scene(
            up=up, object=placement, domain=domain,
            gravity=self.vec3(d.get("gravity", [0.0, 0.0, -9.81]), "gravity"),
            ground=ground, walls=walls,
            damping=self.number(d, "damping", "", 0.0, lo=0.0),
            air_drag=self.number(d, "air_drag", "", 0.0, lo=0.0),
            wind=[self.wind(w, f"wind[{i}]") for i, w in enumerate(self.items(d, "wind"))],
            impulses=[self.impulse(w, f"impulses[{i}]") for i, w in enumerate(self.items(d, "impulses"))],
            fixed=[self.fixed(w, f"fixed[{i}]") for i, w in enumerate(self.items(d, "fixed"))],
            part_overrides=self.overrides(d.get("part_overrides", {})),
            solver=self.solver(d.get("solver", {})),
            materials=self.materials(d.get("materials", {})),
        )
        return scene

    def check_grid_memory(self, scene: Scene) -> None:
        """InputError (with the figure) when the grid's nodes cannot fit in this machine's memory."""
        from ..limits import require_memory

        dims = scene.grid_dims
        nodes = dims[0] * dims[1] * dims[2]
        try:
            require_memory(nodes * GRID_BYTES_PER_NODE, f"a simulation grid of {dims[0]}×{dims[1]}×{dims[2]} nodes",
                           self.source)
        except InputError as exc:
            raise self.fail("domain.grid", str(exc).split(": ", 1)[-1]) from None

    def wind(self, value: Any, key: str) -> Wind:
        w = self.table(value, key, tuple(Wind.__dataclass_fields__))
        if "acceleration" not in w:
            raise self.fail(key, "a wind needs 'acceleration' (m/s², world axes)")
        start = self.number(w, "start_s", key, 0.0, lo=0.0)
        end = self.number(w, "end_s", key, None, lo=0.0, allow_none=True)
        if end is not None and end < start:
            raise self.fail(f"{key}.end_s", "must be ≥ start_s")
        return Wind(self.vec3(w["acceleration"], f"{key}.acceleration"), self.region(w.get("region"), f"{key}.region"),
                    start, end, self.number(w, "gust_amplitude", key, 0.0, lo=0.0),
                    self.number(w, "gust_frequency_hz", key, 0.0, lo=0.0))

    def impulse(self, value: Any, key: str) -> Impulse:
        i = self.table(value, key, tuple(Impulse.__dataclass_fields__))
        if "velocity_change" not in i:
            raise self.fail(key, "an impulse needs 'velocity_change' (m/s)")
        return Impulse(self.number(i, "time_s", key, 0.0, lo=0.0),
                       self.vec3(i["velocity_change"], f"{key}.velocity_change"),
                       self.region(i.get("region"), f"{key}.region"))

    def fixed(self, value: Any, key: str) -> FixedSpec:
        f = self.table(value, key, ("region", "part_ids"))
        ids = f.get("part_ids", [])
        if not isinstance(ids, list) or not all(isinstance(p, int) and not isinstance(p, bool)
                                                and abs(p) <= 2 ** 31 - 1 for p in ids):
            raise self.fail(f"{key}.part_ids", "must be a list of integer part ids")
        spec = FixedSpec(self.region(f.get("region"), f"{key}.region"), [int(p) for p in ids])
        if spec.region is None and not spec.part_ids:
            raise self.fail(key, "give a 'region' and/or 'part_ids'")
        return spec

    def overrides(self, value: Any) -> dict[int, PartOverride]:
        if not isinstance(value, dict):
            raise self.fail("part_overrides", "must be a JSON object keyed by part id")
        out: dict[int, PartOverride] = {}
        for name, entry in value.items():
            key = f"part_overrides.{name}"
            try:
                part = int(name)
                if abs(part) > 2 ** 31 - 1:
                    raise ValueError(name)
            except ValueError:
                raise self.fail(key, "part ids must be integers") from None
            o = self.table(entry, key, tuple(PartOverride.__dataclass_fields__))
            out[part] = PartOverride(
                self.number(o, "E_scale", key, 1.0, lo=0.0, lo_open=True),
                self.number(o, "density_scale", key, 1.0, lo=0.0, lo_open=True),
                self.number(o, "yield_stress_pa", key, None, lo=0.0, lo_open=True, allow_none=True),
                self.boolean(o, "fixed", key, False))
        return out

    def solver(self, value: Any) -> SolverSettings:
        s = self.table(value, "solver", tuple(SolverSettings.__dataclass_fields__))
        return SolverSettings(self.number(s, "cfl", "solver", 0.4, lo=0.0, hi=1.0, lo_open=True),
                              self.number(s, "velocity_cfl", "solver", 0.25, lo=0.0, hi=1.0, lo_open=True),
                              self.integer(s, "max_substeps_per_frame", "solver", 2000, lo=1, hi=10_000_000),
                              self.integer(s, "particles_per_cell", "solver", 8, lo=1, hi=64),
                              self.choice(s, "stiff_parts", "solver", STIFF_PART_MODES))

    def materials(self, value: Any) -> MaterialSettings:
        m = self.table(value, "materials", tuple(MaterialSettings.__dataclass_fields__))
        k = "materials"
        return MaterialSettings(
            self.number(m, "sand_friction_angle_deg", k, 25.0, lo=0.0, hi=60.0),
            self.number(m, "snow_critical_compression", k, 2.5e-2, lo=0.0, hi=0.99),
            self.number(m, "snow_critical_stretch", k, 7.5e-3, lo=0.0),
            self.number(m, "snow_hardening", k, 10.0, lo=0.0),
            self.number(m, "metal_yield_strain", k, 1e-3, lo=0.0, lo_open=True),
            self.number(m, "viscoplastic_yield_strain", k, 1e-3, lo=0.0, lo_open=True),
            self.number(m, "viscoplastic_viscosity_pa_s", k, 10.0, lo=0.0),
            self.number(m, "fluid_viscosity_pa_s", k, 0.0, lo=0.0),
        )
