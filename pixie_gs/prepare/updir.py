"""Up directions: parse what the user gives (`z`, `-y`, `0,-1,-0.6`, `auto`) and turn a unit up
vector into the rotation that makes it +z (the frame the field, the model and the simulator use)."""
from __future__ import annotations

import argparse
import math

import numpy as np

from ..errors import InputError

AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
UP_HELP = ("direction that points up in the file: an axis (z, y, -y, …), a vector such as 0,-1,-0.6, "
           "or auto (default: estimated from a floor/table plane or the object's own shape)")


def parse_up(value: "str | np.ndarray | list | tuple | None") -> "np.ndarray | None":
    """Unit vector (3,) for an axis name ("y", "-y", "+z"), a vector ("0,-1,-0.6" or a sequence),
    or None for "auto"/None. InputError for anything else."""
    if value is None:
        return None
    if not isinstance(value, str):
        v = np.asarray(value, np.float64).reshape(-1)
        return _unit(v, str(list(value)))
    text = value.strip().lower()
    if text in ("", "auto"):
        return None
    sign = -1.0 if text.startswith("-") else 1.0
    name = text.lstrip("+-")
    if name in AXES and text.count("-") + text.count("+") <= 1:
        return sign * np.asarray(AXES[name])
    parts = text.replace(" ", ",").split(",")
    parts = [p for p in parts if p]
    try:
        numbers = [float(p) for p in parts]
    except ValueError:
        numbers = []
    if len(numbers) != 3:
        raise InputError(f"--up '{value}' is not an axis (x, y, z, -x, -y, -z), a vector 'a,b,c' or 'auto'")
    return _unit(np.asarray(numbers), value)


def _unit(v: np.ndarray, text: str) -> np.ndarray:
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
        raise InputError(f"--up '{text}' must be 3 finite numbers, not all zero")
    return v / np.linalg.norm(v)


def up_argument(value: str) -> str:
    """argparse `type=` for --up: checks the text early (exit code 2 on a bad value), keeps it as text."""
    try:
        parse_up(value)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def add_up_option(parser: argparse.ArgumentParser, default: str = "auto") -> None:
    """The one --up option every command shares (`--up -y` works: argparse would otherwise read
    "-y" as an unknown option; see `fix_negative_up`)."""
    parser.add_argument("--up", type=up_argument, default=default, metavar="UP", help=UP_HELP)


def fix_negative_up(argv: list[str]) -> list[str]:
    """Join `--up -y` / `--up -0.1,1,0` into `--up=-y` so argparse does not take the value for an option."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] == "--up" and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"--up={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


DECLARED_PREFIX = "pixie up"  # PLY header comment "pixie up X Y Z": the up a file declares (written by convert)


def declared_up(comments: "list[str] | None") -> "np.ndarray | None":
    """Unit up vector (3,) a file declares in a header comment `pixie up X Y Z` (written by
    `pixie convert` for glTF input, whose spec defines +Y as up), or None."""
    for line in comments or []:
        words = line.strip().split()
        if len(words) == 5 and " ".join(words[:2]).lower() == DECLARED_PREFIX:
            try:
                v = np.asarray([float(w) for w in words[2:]])
            except ValueError:
                continue
            if np.isfinite(v).all() and np.linalg.norm(v) > 1e-12:
                return v / np.linalg.norm(v)
    return None


def rotation_to_z(up: "np.ndarray | str") -> np.ndarray:
    """Proper rotation (3,3) R with R·up = +z: the smallest turn (Rodrigues); a half turn about x
    for up = −z. For the six axes this equals the tables used before vectors were allowed."""
    u = parse_up(up) if isinstance(up, str) else _unit(np.asarray(up, np.float64).reshape(-1), str(up))
    if u is None:
        raise InputError("rotation_to_z needs a direction, not 'auto'")
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(u, z))
    if c > 1.0 - 1e-12:
        return np.eye(3)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    k = np.cross(u, z)
    s = float(np.linalg.norm(k))
    k /= s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def turn(points: np.ndarray, R: np.ndarray) -> np.ndarray:
    """points (N,3) turned by R (3,3): R·p for every row. einsum, because BLAS's (N,3)@(3,3) is
    ~10× slower on some CPUs for this tall, thin shape."""
    return np.einsum("ij,nj->ni", R, points)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (degrees) between two directions."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def nearest_axis(u: np.ndarray) -> tuple[str, float]:
    """(name of the file axis nearest to `u`, e.g. "-y"; angle in degrees between them)."""
    best = ("z", 180.0)
    for name, v in AXES.items():
        for sign, prefix in ((1.0, ""), (-1.0, "-")):
            a = angle_deg(u, sign * np.asarray(v))
            if a < best[1]:
                best = (prefix + name, a)
    return best


def describe_up(u: np.ndarray) -> str:
    """Short text: the axis name when `u` is one, else the rounded vector."""
    name, ang = nearest_axis(u)
    return name if ang < 1e-6 else ",".join(f"{c:.3f}" for c in u)
