"""Class table (pixie_gs/data/classes.json) and part-wise label sampling with rejection.

Each class lists parts with ranges of density (kg/m³), Young's modulus E (Pa) and Poisson ratio ν,
a constitutive material, an optional presence probability, and constraints between parts
("leaves.E < trunk.E", "pot.E > 10*trunk.E"). Sampling follows the Pixie labelling: ν uniform,
E and density log-uniform inside their ranges, whole-object rejection until all constraints hold.
"""
from __future__ import annotations

import json
import math
import operator
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError, read_json_file
from ..materials import MATERIAL_NAMES

DEFAULT_TABLE = Path(__file__).resolve().parent.parent / "data" / "classes.json"
QUANTITIES = ("E", "density", "nu")
_MATERIAL_IDS = {name: mid for mid, name in MATERIAL_NAMES.items() if name != "background"}
_MATERIAL_IDS["elastic"] = _MATERIAL_IDS["jelly"]
_OPS: dict[str, Callable[[float, float], bool]] = {
    "<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
}
_NUM = r"[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?"
_SIDE = rf"(?:({_NUM})\s*\*\s*)?([A-Za-z_][A-Za-z0-9_]*)\.(E|density|nu)"
_CONSTRAINT_RE = re.compile(rf"^\s*{_SIDE}\s*(<=|>=|<|>)\s*{_SIDE}\s*$")
MAX_REJECTION_TRIES = 10_000


@dataclass(frozen=True)
class PartSpec:
    """One part of a class: its material id and closed ranges (low, high) per quantity."""

    name: str
    part_id: int
    material_id: int
    E_pa: tuple[float, float]
    density_kg_m3: tuple[float, float]
    nu: tuple[float, float]
    presence: float = 1.0

    def range_of(self, quantity: str) -> tuple[float, float]:
        return {"E": self.E_pa, "density": self.density_kg_m3, "nu": self.nu}[quantity]


@dataclass(frozen=True)
class Constraint:
    """`left_factor · left_part.quantity  OP  right_factor · right_part.quantity`."""

    text: str
    left_factor: float
    left_part: str
    left_quantity: str
    op: str
    right_factor: float
    right_part: str
    right_quantity: str

    def parts(self) -> tuple[str, str]:
        return self.left_part, self.right_part

    def holds(self, values: dict[str, dict[str, float]]) -> bool:
        """True when satisfied, or when it names a part absent from `values` (vacuous)."""
        if self.left_part not in values or self.right_part not in values:
            return True
        lhs = self.left_factor * values[self.left_part][self.left_quantity]
        rhs = self.right_factor * values[self.right_part][self.right_quantity]
        return _OPS[self.op](lhs, rhs)


@dataclass(frozen=True)
class ClassSpec:
    """A dataset class: geometry recipe, ordered parts (part_id = position) and constraints."""

    name: str
    recipe: str
    parts: tuple[PartSpec, ...]
    constraints: tuple[Constraint, ...]
    part_map: dict[str, str] = field(default_factory=dict)

    def part(self, name: str) -> PartSpec:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(name)


def parse_constraint(text: str, where: str) -> Constraint:
    """Parse 'a.E < b.E' / 'a.E > 10*b.E' (factor on either side); InputError when malformed."""
    m = _CONSTRAINT_RE.match(text)
    if not m:
        raise InputError(f"{where}: cannot parse constraint {text!r} (expected e.g. 'leaves.E < trunk.E' "
                         "or 'pot.E > 10*trunk.E')")
    lf, lp, lq, op, rf, rp, rq = m.groups()
    return Constraint(text=text.strip(), left_factor=float(lf or 1.0), left_part=lp, left_quantity=lq,
                      op=op, right_factor=float(rf or 1.0), right_part=rp, right_quantity=rq)


def _range(value: object, quantity: str, widen: dict, where: str) -> tuple[float, float]:
    """A (low, high) range from a [low, high] pair or a single centre value widened per `widen`."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        c = float(value)
        if quantity == "nu":
            lo, hi = c - widen["nu_abs"], c + widen["nu_abs"]
        else:
            rel = widen["E_rel"] if quantity == "E" else widen["density_rel"]
            lo, hi = c * (1 - rel), c * (1 + rel)
    elif isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value):
        lo, hi = float(value[0]), float(value[1])
    else:
        raise InputError(f"{where}.{quantity}: expected a number or [low, high], got {value!r}")
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise InputError(f"{where}.{quantity}: range [{lo}, {hi}] is empty or not finite")
    if quantity == "nu" and not (0.0 < lo and hi < 0.5):
        raise InputError(f"{where}.nu: range [{lo}, {hi}] must lie inside (0, 0.5)")
    if quantity != "nu" and lo <= 0:
        raise InputError(f"{where}.{quantity}: range [{lo}, {hi}] must be positive")
    return lo, hi


def _parse_class(name: str, raw: dict, widen: dict, source: str) -> ClassSpec:
    where = f"{source}: class '{name}'"
    if not isinstance(raw, dict) or "recipe" not in raw or "parts" not in raw:
        raise InputError(f"{where}: needs 'recipe' and 'parts'")
    if not isinstance(raw["parts"], dict) or not raw["parts"]:
        raise InputError(f"{where}: 'parts' must be a non-empty object")
    parts = []
    for pid, (pname, praw) in enumerate(raw["parts"].items()):
        pwhere = f"{where} part '{pname}'"
        material = praw.get("material")
        if material not in _MATERIAL_IDS:
            raise InputError(f"{pwhere}: unknown material {material!r} (one of {', '.join(_MATERIAL_IDS)})")
        for q in QUANTITIES:
            if q not in praw:
                raise InputError(f"{pwhere}: missing '{q}'")
        presence = float(praw.get("presence", 1.0))
        if not 0.0 < presence <= 1.0:
            raise InputError(f"{pwhere}: presence must be in (0, 1], got {presence}")
        parts.append(PartSpec(
            name=pname, part_id=pid, material_id=_MATERIAL_IDS[material],
            E_pa=_range(praw["E"], "E", widen, pwhere),
            density_kg_m3=_range(praw["density"], "density", widen, pwhere),
            nu=_range(praw["nu"], "nu", widen, pwhere), presence=presence,
        ))
    if all(p.presence < 1.0 for p in parts):
        raise InputError(f"{where}: at least one part must always be present (presence 1)")
    names = {p.name for p in parts}
    constraints = []
    for text in raw.get("constraints", []):
        c = parse_constraint(text, where)
        unknown = [p for p in c.parts() if p not in names]
        if unknown:
            raise InputError(f"{where}: constraint {text!r} names unknown part(s) {', '.join(unknown)}")
        constraints.append(c)
    part_map = dict(raw.get("part_map", {}))
    return ClassSpec(name=name, recipe=str(raw["recipe"]), parts=tuple(parts),
                     constraints=tuple(constraints), part_map=part_map)


def load_class_table(path: str | Path | None = None) -> dict[str, ClassSpec]:
    """Read and validate the class table (default: the packaged classes.json), in file order."""
    path = Path(path) if path is not None else DEFAULT_TABLE
    if not path.exists():
        raise InputError("no such class table", path)
    raw = read_json_file(path, "a class table")
    if not isinstance(raw, dict) or not isinstance(raw.get("classes"), dict) or not raw["classes"]:
        raise InputError("needs a non-empty 'classes' object", path)
    widen_raw = raw.get("widen", {})
    if not isinstance(widen_raw, dict) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 <= v < 1
            for v in widen_raw.values()):
        raise InputError("'widen' must map E_rel/density_rel/nu_abs to numbers in [0, 1)", path)
    widen = {"E_rel": 0.2, "density_rel": 0.2, "nu_abs": 0.03, **widen_raw}
    try:
        return {name: _parse_class(name, craw, widen, str(path)) for name, craw in raw["classes"].items()}
    except (TypeError, ValueError, AttributeError, KeyError, OverflowError) as exc:  # wrong JSON types
        text = str(exc).splitlines()[0][:120] if str(exc) else ""
        raise InputError(f"malformed class table (a value of the wrong type: {type(exc).__name__} {text})",
                         path) from None


def table_extremes(table: dict[str, ClassSpec] | None = None) -> dict[str, tuple[float, float]]:
    """(lowest, highest) of every part's range per quantity ("E" Pa, "nu", "density" kg/m³) over the class
    table (default: the packaged one): the span every generated label lies in, and the span a teacher's
    labels are clipped to (pixie_gs/dataset/teacher_pool.py) so that no label leaves the vocabulary."""
    parts = [p for c in (table if table is not None else load_class_table()).values() for p in c.parts]
    return {q: (min(p.range_of(q)[0] for p in parts), max(p.range_of(q)[1] for p in parts)) for q in QUANTITIES}


def sample_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def sample_log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """exp(U(log lo, log hi)), clipped into [lo, hi] against rounding at the ends."""
    return float(min(max(math.exp(rng.uniform(math.log(lo), math.log(hi))), lo), hi))


def choose_parts(spec: ClassSpec, rng: np.random.Generator) -> list[str]:
    """Names of the parts this object has (optional parts drawn with their presence probability)."""
    return [p.name for p in spec.parts if p.presence >= 1.0 or rng.random() < p.presence]


def sample_part_values(spec: ClassSpec, present: list[str], rng: np.random.Generator,
                       max_tries: int = MAX_REJECTION_TRIES) -> tuple[dict[str, dict[str, float]], int]:
    """Draw (E Pa, ν, density kg/m³) per present part until all constraints hold.

    Returns the values and the number of draws it took; float32-representable values are
    returned (they are stored as float32), and constraints are checked on exactly those.
    """
    for attempt in range(1, max_tries + 1):
        values = {}
        for name in present:
            p = spec.part(name)
            values[name] = {
                "E": _f32(sample_log_uniform(rng, *p.E_pa), p.E_pa),
                "nu": _f32(sample_uniform(rng, *p.nu), p.nu),
                "density": _f32(sample_log_uniform(rng, *p.density_kg_m3), p.density_kg_m3),
            }
        if all(c.holds(values) for c in spec.constraints):
            return values, attempt
    raise InputError(f"class '{spec.name}': constraints {[c.text for c in spec.constraints]} were not "
                     f"satisfied in {max_tries} draws; are the ranges consistent?")


def _f32(value: float, bounds: tuple[float, float]) -> float:
    """`value` rounded to float32, nudged back inside `bounds` if rounding pushed it out."""
    v = np.float32(value)
    lo, hi = bounds
    if float(v) < lo:
        v = np.nextafter(v, np.float32(np.inf))
    if float(v) > hi:
        v = np.nextafter(v, np.float32(-np.inf))
    return float(v)


def check_object_labels(spec: ClassSpec, parts: dict[str, dict[str, float]]) -> list[str]:
    """Problems with an object's part values (empty list when every value is in range and every
    constraint holds). Used by tests and the benchmark to audit generated data."""
    problems = []
    for name, vals in parts.items():
        try:
            p = spec.part(name)
        except KeyError:
            problems.append(f"unknown part {name!r}")
            continue
        for q in QUANTITIES:
            lo, hi = p.range_of(q)
            if not lo <= vals[q] <= hi:
                problems.append(f"{name}.{q}={vals[q]} outside [{lo}, {hi}]")
        if "material_id" in vals and vals["material_id"] != p.material_id:
            problems.append(f"{name}.material_id={vals['material_id']} != {p.material_id}")
    for c in spec.constraints:
        if not c.holds(parts):
            problems.append(f"constraint {c.text!r} violated")
    return problems
