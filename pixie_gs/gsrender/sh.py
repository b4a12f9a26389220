"""View-dependent colour from real spherical harmonics (degrees 0–3), as 3DGS stores them.

`basis(dirs)` gives the 16 real SH basis functions (with the Condon–Shortley phase, in the
order l = 0..3, m = −l..l) at unit directions; a Gaussian's colour seen along direction d
(from the camera to its centre) is max(0, 0.5 + Σ_k basis_k(d) · coeff_k) per channel.
Works on numpy arrays and torch tensors alike (only arithmetic on the inputs).
"""
from __future__ import annotations

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)
COEFFS_PER_DEGREE = {0: 1, 1: 4, 2: 9, 3: 16}


def basis(x, y, z, degree: int) -> list:
    """The (degree+1)² basis values at unit direction components x, y, z (arrays or tensors)."""
    out = [C0 + 0.0 * x]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
                C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)]
    return out


def coefficients(sh_dc: np.ndarray, sh_rest: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K, 3), K = (degree+1)², from f_dc (N,3) and f_rest (N, 3·(K−1)) stored
    channel-major (all R coefficients, then all G, then all B), as INRIA 3DGS files hold them."""
    n = len(sh_dc)
    rest = np.asarray(sh_rest, np.float32).reshape(n, 3, -1).transpose(0, 2, 1)
    return np.concatenate([np.asarray(sh_dc, np.float32)[:, None, :], rest], axis=1)


def degree_of(count: int) -> int:
    """SH degree from the number of coefficients per channel (1, 4, 9 or 16)."""
    for degree, k in COEFFS_PER_DEGREE.items():
        if k == count:
            return degree
    raise ValueError(f"{count} SH coefficients per channel is not a full degree 0–3 set")
