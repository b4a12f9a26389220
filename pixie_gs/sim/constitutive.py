"""Constitutive models of the MPM (Warp functions, compiled into the kernels of sim/kernels.py).

After F ← (I + dt·C)·F, `update_material` projects the trial elastic F back onto the material's
yield surface (return mapping) and returns the Kirchhoff stress τ = P Fᵀ (Pa) of the result, reusing
the SVD of the return mapping, so the next P2G only reads the stored stress.
Ids follow pixie_gs.materials: 0 jelly, 1 metal, 2 sand, 3 visco-plastic, 4 fluid, 5 snow,
6 stationary. Yield stresses are uniaxial (von Mises: √(3/2)‖dev τ‖ ≤ σ_y).
"""
from __future__ import annotations

import warp as wp

NO_YIELD = 1.0e30  # yield stress (Pa) meaning "never yields" (np.inf is mapped to this)
MIN_STRETCH = 1.0e-4  # singular values are clamped above this before taking logs


@wp.struct
class MaterialParams:
    """Model parameters shared by all particles (from Scene.materials)."""

    sand_alpha: float  # Drucker–Prager cone slope √(2/3)·2 sin φ / (3 − sin φ)
    snow_theta_c: float  # critical compression θc
    snow_theta_s: float  # critical stretch θs
    snow_hardening: float  # ξ
    viscoplastic_viscosity: float  # η (Pa·s) of the Perzyna flow
    fluid_viscosity: float  # Pa·s


@wp.func
def polar_rotation(F: wp.mat33) -> wp.mat33:
    """Rotation R of the polar decomposition F = R S.

    Scaled Newton iteration X ← ½(γX + X⁻ᵀ/γ) (Higham 1986): a few 3×3 inverses, ~4× cheaper
    than an SVD. Nearly flat or inverted F (J < 0.05) take the SVD, whose rotation is always proper.
    """
    J = wp.determinant(F)
    if not (J > 0.05):
        U, sig, V = wp.svd3(F)
        return U * wp.transpose(V)
    X = F
    for _ in range(12):
        Xi = wp.inverse(X)
        g = wp.sqrt(wp.sqrt(wp.ddot(Xi, Xi) / wp.ddot(X, X)))
        Xn = 0.5 * (g * X + wp.transpose(Xi) / g)
        step = wp.ddot(Xn - X, Xn - X)
        X = Xn
        if step < 1.0e-12:
            break
    return X


@wp.func
def fixed_corotated_stress(F: wp.mat33, mu: float, lam: float) -> wp.mat33:
    """τ = 2μ(F − R)Fᵀ + λ(J − 1)J·I, R the rotation of F (Stomakhin et al. 2012)."""
    R = polar_rotation(F)
    J = wp.determinant(F)
    return 2.0 * mu * (F - R) * wp.transpose(F) + wp.identity(n=3, dtype=float) * (lam * (J - 1.0) * J)


@wp.func
def corotated_stress_from_svd(U: wp.mat33, s: wp.vec3, mu: float, lam: float) -> wp.mat33:
    """Fixed-corotated τ for F = U diag(s) Vᵀ: U diag(2μ(s − 1)s + λ(J − 1)J) Uᵀ."""
    J = s[0] * s[1] * s[2]
    p = lam * (J - 1.0) * J
    d = wp.vec3(2.0 * mu * (s[0] - 1.0) * s[0] + p, 2.0 * mu * (s[1] - 1.0) * s[1] + p,
                2.0 * mu * (s[2] - 1.0) * s[2] + p)
    return U * wp.diag(d) * wp.transpose(U)


@wp.func
def log_stretches(sig: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.log(wp.max(sig[0], MIN_STRETCH)), wp.log(wp.max(sig[1], MIN_STRETCH)),
                   wp.log(wp.max(sig[2], MIN_STRETCH)))


@wp.func
def exp3(e: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.exp(e[0]), wp.exp(e[1]), wp.exp(e[2]))


@wp.func
def update_material(F: wp.mat33, C: wp.mat33, mu: float, lam: float, material: int, yield_stress: float,
                    Jp: float, dt: float, mp: MaterialParams):
    """Return mapping of the trial F and the stress of the result: (F_new, Jp_new, τ).

    0 jelly: elastic (von Mises like metal when its yield stress is finite); 1 metal: von Mises in
    Hencky strain, √(3/2)‖dev τ‖ ≤ σ_y; 2 sand: cohesionless Drucker–Prager (Klár et al. 2016),
    expansion is stress-free; 3 visco-plastic: Perzyna flow, a fraction dt/(dt + η/2μ) of the excess
    per substep; 4 fluid: F ← J^(1/3) I, pressure K(J − 1)J plus Newtonian viscosity; 5 snow:
    stretches clamped to [1 − θc, 1 + θs], Jp tracks the plastic volume, μ, λ × exp(ξ(1 − Jp))
    (Stomakhin et al. 2013); 6 stationary: no stress.
    """
    eye = wp.identity(n=3, dtype=float)
    if material == 6:
        return F, Jp, wp.mat33(0.0)
    if material == 4:
        J = wp.max(wp.determinant(F), 1.0e-6)
        K = lam + 2.0 * mu / 3.0
        tau = eye * (K * (J - 1.0) * J) + mp.fluid_viscosity * J * (C + wp.transpose(C))
        return eye * wp.pow(J, 1.0 / 3.0), Jp, tau
    if material == 2:
        U, sig, V = wp.svd3(F)
        e = log_stretches(sig)
        tr = e[0] + e[1] + e[2]
        if tr >= 0.0:
            e = wp.vec3(0.0)
        else:
            e_dev = e - wp.vec3(tr / 3.0, tr / 3.0, tr / 3.0)
            n = wp.length(e_dev)
            dgamma = n + (3.0 * lam + 2.0 * mu) / (2.0 * mu) * tr * mp.sand_alpha
            if dgamma > 0.0 and n > 1.0e-12:
                e = e - (dgamma / n) * e_dev
        tr = e[0] + e[1] + e[2]
        t = 2.0 * mu * e + wp.vec3(lam * tr, lam * tr, lam * tr)
        return U * wp.diag(exp3(e)) * wp.transpose(V), Jp, U * wp.diag(t) * wp.transpose(U)
    if material == 5:
        U, sig, V = wp.svd3(F)
        s = wp.vec3(wp.clamp(sig[0], 1.0 - mp.snow_theta_c, 1.0 + mp.snow_theta_s),
                    wp.clamp(sig[1], 1.0 - mp.snow_theta_c, 1.0 + mp.snow_theta_s),
                    wp.clamp(sig[2], 1.0 - mp.snow_theta_c, 1.0 + mp.snow_theta_s))
        Jp_new = wp.clamp(Jp * (sig[0] * sig[1] * sig[2]) / (s[0] * s[1] * s[2]), 0.2, 5.0)
        h = wp.exp(mp.snow_hardening * (1.0 - Jp_new))
        return U * wp.diag(s) * wp.transpose(V), Jp_new, corotated_stress_from_svd(U, s, mu * h, lam * h)
    if material == 3 or ((material == 0 or material == 1) and yield_stress < NO_YIELD):
        fraction = 1.0
        if material == 3:
            fraction = dt / (dt + mp.viscoplastic_viscosity / (2.0 * mu))
        U, sig, V = wp.svd3(F)
        e = log_stretches(sig)
        tr = e[0] + e[1] + e[2]
        e_dev = e - wp.vec3(tr / 3.0, tr / 3.0, tr / 3.0)
        n = wp.length(e_dev)
        dgamma = n - wp.sqrt(2.0 / 3.0) * yield_stress / (2.0 * mu)
        if dgamma > 0.0 and n > 1.0e-12:
            s = exp3(e - (fraction * dgamma / n) * e_dev)
            return U * wp.diag(s) * wp.transpose(V), Jp, corotated_stress_from_svd(U, s, mu, lam)
        return F, Jp, corotated_stress_from_svd(U, sig, mu, lam)
    return F, Jp, fixed_corotated_stress(F, mu, lam)
