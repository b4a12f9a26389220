"""The brute-force definition of a 3DGS image, for tests: slow, plain, float64.

For every pixel, every Gaussian is evaluated; those with α ≥ 1/255 are sorted by view depth and
composited front to back one at a time (α clamped to 0.99, stop before transmittance < 1e-4).
Written apart from the fast rasteriser on purpose: numpy instead of torch, no tiles or footprint
bounds, covariance from scipy's rotation, and SH basis values from scipy's complex spherical
harmonics (real form with the Condon–Shortley phase: √2·Im Y_l^|m| for m < 0, Y_l^0, √2·Re Y_l^m
for m > 0), not from the polynomial table the fast path uses.
"""
from __future__ import annotations

import numpy as np

from .camera import Camera


def real_sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """(N, (degree+1)²) real SH basis values at unit directions (N,3), 3DGS order and signs."""
    try:
        from scipy.special import sph_harm_y  # scipy ≥ 1.15
    except ImportError:  # older scipy: sph_harm(m, l, azimuth, polar)
        from scipy.special import sph_harm

        def sph_harm_y(l, m, polar, azimuth):
            return sph_harm(m, l, azimuth, polar)

    d = np.asarray(dirs, np.float64)
    theta = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi = np.arctan2(d[:, 1], d[:, 0])
    cols = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            Y = sph_harm_y(l, abs(m), theta, phi)
            cols.append(np.sqrt(2) * Y.imag if m < 0 else (Y.real if m == 0 else np.sqrt(2) * Y.real))
    return np.stack(cols, axis=1)


def reference_render(means: np.ndarray, scales: np.ndarray, quats_wxyz: np.ndarray, opacities: np.ndarray,
                     sh_coeffs: np.ndarray | None, cam: Camera, colours: np.ndarray | None = None,
                     background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Image (H,W,3) float64 of N Gaussians: centres (N,3), std-devs (N,3), quaternions w,x,y,z
    (N,4), opacities (N,), SH coefficients (N,K,3) or fixed `colours` (N,3)."""
    from scipy.spatial.transform import Rotation

    means = np.asarray(means, np.float64)
    q = np.asarray(quats_wxyz, np.float64)
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy wants x,y,z,w
    sigma = rot @ (np.asarray(scales, np.float64)[:, :, None] ** 2 * np.transpose(rot, (0, 2, 1)))
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    p = means @ R.T + t
    if colours is None:
        view = means - cam.centre
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        k = sh_coeffs.shape[1]
        basis = real_sh_basis(view, int(round(np.sqrt(k))) - 1)
        colours = np.maximum(np.einsum("nk,nkc->nc", basis, sh_coeffs) + 0.5, 0.0)
    colours = np.asarray(colours, np.float64)

    gauss2d = []  # (depth, index, mean (2,), inverse covariance (2,2), opacity) of the visible ones
    for i in range(len(means)):
        x, y, z = p[i]
        if z <= cam.near or opacities[i] < 1.0 / 255.0:
            continue
        # the 3DGS Jacobian is evaluated at the centre clamped to 1.3× the field of view
        tx, ty = 0.5 * cam.width / cam.fx, 0.5 * cam.height / cam.fy
        u = min(max(x / z, -(cam.cx / cam.fx + 0.3 * tx)), (cam.width - cam.cx) / cam.fx + 0.3 * tx)
        v = min(max(y / z, -(cam.cy / cam.fy + 0.3 * ty)), (cam.height - cam.cy) / cam.fy + 0.3 * ty)
        J = np.array([[cam.fx / z, 0.0, -cam.fx * u / z], [0.0, cam.fy / z, -cam.fy * v / z]])
        cov = J @ R @ sigma[i] @ R.T @ J.T + 0.3 * np.eye(2)
        if np.linalg.det(cov) <= 0:
            continue
        centre = np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy])
        gauss2d.append((z, i, centre, np.linalg.inv(cov), float(opacities[i])))
    gauss2d.sort(key=lambda item: (item[0], item[1]))

    image = np.empty((cam.height, cam.width, 3))
    for row in range(cam.height):
        for col in range(cam.width):
            pixel = np.array([col + 0.5, row + 0.5])
            colour, T = np.zeros(3), 1.0
            for _, i, centre, inv, opacity in gauss2d:
                d = pixel - centre
                alpha = min(0.99, opacity * np.exp(-0.5 * d @ inv @ d))
                if alpha < 1.0 / 255.0:
                    continue
                if T * (1.0 - alpha) < 1e-4:
                    break
                colour += T * alpha * colours[i]
                T *= 1.0 - alpha
            image[row, col] = colour + T * np.asarray(background, np.float64)
    return image
