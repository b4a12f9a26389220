"""Constitutive models of the MPM (Warp functions, compiled into the kernels of sim/kernels.py).

Stress: Kirchhoff τ = P Fᵀ (Pa) per material id; plasticity: return mappings that project the
trial elastic F back onto each model's yield surface after F ← (I + dt·C)·F.
Ids follow pixie_gs.materials: 0 jelly, 1 metal, 2 sand, 3 visco-plastic, 4 fluid, 5 snow,
6 stationary. Yield stresses are uniaxial (von Mises: √(3/2)‖dev τ‖ ≤ σ_y).
"""
from __future__ import annotations

import warp as wp

NO_YIELD = 1.0e30  # yield stress (Pa) meaning "never yields" (np.inf is mapped to this)
MIN_STRETCH = 1.0e-4  # singular values are clamped above this before taking logs


@wp.func
def fixed_corotated_stress(F: wp.mat33, mu: float, lam: float) -> wp.mat33:
    """τ = 2μ(F − R)Fᵀ + λ(J − 1)J·I, R the rotation of F (Stomakhin et al. 2012)."""
    U, sig, V = wp.svd3(F)
    R = U * wp.transpose(V)
    J = sig[0] * sig[1] * sig[2]
    return 2.0 * mu * (F - R) * wp.transpose(F) + wp.identity(n=3, dtype=float) * (lam * (J - 1.0) * J)


@wp.func
def hencky_stress(F: wp.mat33, mu: float, lam: float) -> wp.mat33:
    """St. Venant–Kirchhoff on Hencky strain ε = log Σ: τ = U(2μ ε + λ tr(ε) I)Uᵀ (Klár et al. 2016)."""
    U, sig, V = wp.svd3(F)
    e = wp.vec3(wp.log(wp.max(wp.abs(sig[0]), MIN_STRETCH)), wp.log(wp.max(wp.abs(sig[1]), MIN_STRETCH)),
                wp.log(wp.max(wp.abs(sig[2]), MIN_STRETCH)))
    tr = e[0] + e[1] + e[2]
    t = 2.0 * mu * e + wp.vec3(lam * tr, lam * tr, lam * tr)
    return U * wp.diag(t) * wp.transpose(U)


@wp.func
def kirchhoff_stress(F: wp.mat33, C: wp.mat33, mu: float, lam: float, material: int, Jp: float,
                     snow_hardening: float, fluid_viscosity: float) -> wp.mat33:
    """Kirchhoff stress (Pa) of one particle with deformation gradient F and velocity gradient C."""
    if material == 2:  # sand
        return hencky_stress(F, mu, lam)
    if material == 4:  # fluid: pressure from J with bulk modulus K = λ + 2μ/3, plus Newtonian viscosity
        J = wp.determinant(F)
        K = lam + 2.0 * mu / 3.0
        return wp.identity(n=3, dtype=float) * (K * (J - 1.0) * J) + fluid_viscosity * J * (C + wp.transpose(C))
    if material == 5:  # snow: Lamé parameters harden/soften with plastic volume change Jp
        h = wp.exp(snow_hardening * (1.0 - Jp))
        return fixed_corotated_stress(F, mu * h, lam * h)
    if material == 6:  # stationary: never deformed
        return wp.mat33(0.0)
    return fixed_corotated_stress(F, mu, lam)


@wp.func
def log_stretches(sig: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.log(wp.max(sig[0], MIN_STRETCH)), wp.log(wp.max(sig[1], MIN_STRETCH)),
                   wp.log(wp.max(sig[2], MIN_STRETCH)))


@wp.func
def von_mises_return(F: wp.mat33, mu: float, yield_stress: float, flow_fraction: float) -> wp.mat33:
    """Project F onto the von Mises surface in Hencky strain; flow_fraction < 1 relaxes only part
    of the excess per step (Perzyna visco-plasticity), 1 = perfect plasticity."""
    U, sig, V = wp.svd3(F)
    e = log_stretches(sig)
    tr = e[0] + e[1] + e[2]
    e_dev = e - wp.vec3(tr / 3.0, tr / 3.0, tr / 3.0)
    n = wp.length(e_dev)
    dgamma = n - wp.sqrt(2.0 / 3.0) * yield_stress / (2.0 * mu)
    if dgamma <= 0.0 or n < 1.0e-12:
        return F
    e = e - (flow_fraction * dgamma / n) * e_dev
    s = wp.vec3(wp.exp(e[0]), wp.exp(e[1]), wp.exp(e[2]))
    return U * wp.diag(s) * wp.transpose(V)


@wp.func
def drucker_prager_return(F: wp.mat33, mu: float, lam: float, alpha: float) -> wp.mat33:
    """Sand (Klár et al. 2016): cohesionless Drucker–Prager cone in Hencky strain.
    alpha = √(2/3)·2 sin φ / (3 − sin φ) for friction angle φ. Expansion → stress-free."""
    U, sig, V = wp.svd3(F)
    e = log_stretches(sig)
    tr = e[0] + e[1] + e[2]
    if tr >= 0.0:
        return U * wp.transpose(V)
    e_dev = e - wp.vec3(tr / 3.0, tr / 3.0, tr / 3.0)
    n = wp.length(e_dev)
    if n < 1.0e-12:
        return F
    dgamma = n + (3.0 * lam + 2.0 * mu) / (2.0 * mu) * tr * alpha
    if dgamma <= 0.0:
        return F
    e = e - (dgamma / n) * e_dev
    s = wp.vec3(wp.exp(e[0]), wp.exp(e[1]), wp.exp(e[2]))
    return U * wp.diag(s) * wp.transpose(V)


@wp.func
def snow_return(F: wp.mat33, theta_c: float, theta_s: float) -> wp.mat33:
    """Snow (Stomakhin et al. 2013): clamp elastic stretches to [1 − θc, 1 + θs]."""
    U, sig, V = wp.svd3(F)
    s = wp.vec3(wp.clamp(sig[0], 1.0 - theta_c, 1.0 + theta_s), wp.clamp(sig[1], 1.0 - theta_c, 1.0 + theta_s),
                wp.clamp(sig[2], 1.0 - theta_c, 1.0 + theta_s))
    return U * wp.diag(s) * wp.transpose(V)


@wp.func
def fluid_return(F: wp.mat33) -> wp.mat33:
    """Fluid keeps only its volume change: F ← J^(1/3)·I."""
    J = wp.max(wp.determinant(F), 1.0e-6)
    return wp.identity(n=3, dtype=float) * wp.pow(J, 1.0 / 3.0)
