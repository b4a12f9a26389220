"""Pinhole cameras for the splat renderer: orbit / fixed framing, INRIA cameras.json, nerfstudio
transforms.json.

Convention (as 3DGS / OpenCV): camera axes x right, y down, z forward; a world point X is at
x_cam = R X + t; pixel (u, v) = (fx x/z + cx, fy y/z + cy) with pixel (i, j)'s centre at
(i + 0.5, j + 0.5), so cx = width / 2 puts the optical axis at the image centre.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError, require_file

DEFAULT_FOV_Y_DEG = 40.0
ROBUST_QUANTILE = 0.01  # framing ignores the outermost 1 % of centres on each side (floaters)
FRAME_MARGIN = 1.1  # the framed sphere's radius is this much smaller than the half field of view


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: world-to-camera rotation R (3,3) and translation t (3,) (x_cam = R X + t),
    focal lengths and principal point in px, image size in px, near clipping depth (world units)."""

    R: np.ndarray
    t: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float = 0.01
    name: str = ""

    @property
    def centre(self) -> np.ndarray:
        """Camera position in world coordinates (3,)."""
        return -np.asarray(self.R, np.float64).T @ np.asarray(self.t, np.float64)

    def resized(self, width: int, height: int) -> "Camera":
        """The same view at another image size (focal lengths and principal point scaled)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                       width=int(width), height=int(height))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray, width: int, height: int,
            fov_y_deg: float = DEFAULT_FOV_Y_DEG, near: float = 0.01, name: str = "") -> Camera:
    """A camera at `eye` looking at `target`, `up` pointing up on screen (square pixels)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking along the up axis: any right will do
        right = np.cross(forward, np.roll(up, 1))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2)
    return Camera(R=R, t=-R @ eye, fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, width=int(width),
                  height=int(height), near=near, name=name)


def robust_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) of the points' central 98 % box and the radius around it holding 99 % of the
    points (so a few floaters do not shrink the object in the picture)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        raise InputError("no finite Gaussian centres to frame")
    lo = np.quantile(pts, ROBUST_QUANTILE, axis=0)
    hi = np.quantile(pts, 1 - ROBUST_QUANTILE, axis=0)
    centre = (lo + hi) / 2.0
    radius = float(np.quantile(np.linalg.norm(pts - centre, axis=1), 1 - ROBUST_QUANTILE))
    return centre, max(radius, 1e-6)


def up_basis(up: str | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(azimuth-0 axis, azimuth-90 axis, unit up), right-handed, for an axis name ("z", "-y") or a
    vector (3,)."""
    from ..render import up_frame

    if isinstance(up, str):
        return up_frame(up)
    u = np.asarray(up, np.float64).reshape(3)
    if not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
        raise InputError(f"up vector must be finite and non-zero (got {u.tolist()})")
    u = u / np.linalg.norm(u)
    e = np.eye(3)[int(np.argmin(np.abs(u)))]
    a = e - (e @ u) * u
    a /= np.linalg.norm(a)
    return a, np.cross(u, a), u


def orbit_cameras(points: np.ndarray, count: int, width: int, height: int, up: str | np.ndarray = "z",
                  elevation_deg: float = 20.0, azimuth0_deg: float = -90.0, turns: float = 1.0,
                  fov_y_deg: float = DEFAULT_FOV_Y_DEG) -> list[Camera]:
    """`count` cameras circling the object (robust extent of `points`, up axis like "z" or "-y"),
    elevation above its equator, each framing the whole object. count = 1 gives one fixed view."""
    a, b, u = up_basis(up)
    centre, radius = robust_sphere(points)
    half_fov = np.radians(fov_y_deg) / 2 * min(1.0, width / height)
    distance = FRAME_MARGIN * radius / np.sin(half_fov)
    el = np.radians(elevation_deg)
    cams = []
    for k in range(count):
        az = np.radians(azimuth0_deg + 360.0 * turns * k / max(count, 1))
        direction = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * u
        cams.append(look_at(centre + distance * direction, centre, u, width, height, fov_y_deg,
                            near=max(1e-6, 0.01 * distance), name=f"orbit_{k:03d}"))
    return cams


def read_cameras(path: str | Path) -> list[Camera]:
    """Cameras from an INRIA 3DGS `cameras.json` (list of {id, img_name, width, height, position,
    rotation (camera-to-world 3×3), fx, fy}) or a nerfstudio / instant-ngp `transforms.json`
    ({fl_x, fl_y, cx, cy, w, h, frames: [{transform_matrix (camera-to-world 4×4, OpenGL axes)}]})."""
    path = require_file(path, "a cameras.json / transforms.json file")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a readable JSON file ({exc})", path) from None
    try:
        if isinstance(data, list):
            cams = [_inria_camera(entry) for entry in data]
        elif isinstance(data, dict) and "frames" in data:
            cams = [_nerfstudio_camera(data, frame) for frame in data["frames"]]
        else:
            raise ValueError("expected a list of INRIA cameras or an object with 'frames'")
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"not an INRIA cameras.json or nerfstudio transforms.json ({exc!s})", path) from None
    if not cams:
        raise InputError("holds no cameras", path)
    for cam in cams:
        values = np.concatenate([np.ravel(cam.R), np.ravel(cam.t), [cam.fx, cam.fy, cam.cx, cam.cy]])
        if not np.all(np.isfinite(values)) or cam.width < 1 or cam.height < 1 or cam.fx <= 0 or cam.fy <= 0:
            raise InputError(f"camera {cam.name!r} has non-finite or non-positive values", path)
    return cams


def _inria_camera(entry: dict) -> Camera:
    c2w = np.asarray(entry["rotation"], np.float64).reshape(3, 3)
    position = np.asarray(entry["position"], np.float64).reshape(3)
    width, height = int(entry["width"]), int(entry["height"])
    R = c2w.T
    return Camera(R=R, t=-R @ position, fx=float(entry["fx"]), fy=float(entry["fy"]), cx=width / 2.0,
                  cy=height / 2.0, width=width, height=height,
                  name=str(entry.get("img_name", entry.get("id", ""))))


def _nerfstudio_camera(data: dict, frame: dict) -> Camera:
    def get(key: str, *alt: str):
        for k in (key, *alt):
            if k in frame:
                return frame[k]
            if k in data:
                return data[k]
        raise KeyError(key)

    width, height = int(get("w")), int(get("h"))
    if "fl_x" in frame or "fl_x" in data:
        fx = float(get("fl_x"))
        fy = float(get("fl_y", "fl_x"))
    else:  # instant-ngp files may give only the horizontal field of view (radians)
        fx = 0.5 * width / np.tan(float(get("camera_angle_x")) / 2)
        fy = fx
    c2w = np.asarray(frame["transform_matrix"], np.float64).reshape(4, 4)[:3]
    rot = c2w[:, :3] * np.array([1.0, -1.0, -1.0])  # OpenGL (y up, z back) -> OpenCV (y down, z forward)
    R = rot.T
    cx = float(get("cx")) if ("cx" in frame or "cx" in data) else width / 2.0
    cy = float(get("cy")) if ("cy" in frame or "cy" in data) else height / 2.0
    return Camera(R=R, t=-R @ c2w[:, 3], fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
                  name=str(frame.get("file_path", "")))
