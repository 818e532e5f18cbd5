"""Directional albedo of a BRDF by numerical quadrature.

ρ(wi) = ∫_Ω+ f(wi, wo) cos θ_o dω_o = ∫_0^{π/2} ∫_0^{2π} f(wi, wo(θ, φ)) cos θ sin θ dφ dθ

(the directional-hemispherical reflectance, F. Nicodemus et al., "Geometrical Considerations and
Nomenclature for Reflectance", NBS Monograph 160, 1977; lecture notes ``004_6b0fa14dcb48ed2f.txt``,
energy conservation). Gauss-Legendre in θ_o, the periodic trapezoid rule in φ_o (spectrally accurate
for smooth periodic integrands; φ_o = φ_i + π, the mirror azimuth, is a node). Sharp lobes need
more nodes: the error is about the lobe width over the node spacing; α ≥ 0.05 with the default n is
accurate to ~1e-3.
"""

from __future__ import annotations

import numpy as np

from gonio.geometry import from_spherical

__all__ = ["directional_albedo"]


def directional_albedo(model, theta_i, phi_i=0.0, n: int = 96, chunk: int = 1_000_000) -> np.ndarray:
    """Directional albedo ρ(θ_i, φ_i) of ``model`` (any object with ``eval(wi, wo)``), RGB.

    Parameters
    ----------
    model : gonio.brdf.BRDF
    theta_i, phi_i : array_like
        Incidence angles in radians (broadcast together).
    n : int
        Gauss-Legendre nodes in θ_o; 2n trapezoid nodes in φ_o.
    chunk : int
        Upper bound on the number of BRDF evaluations per call of ``model.eval`` (memory bound).

    Returns
    -------
    ndarray, shape ``broadcast(theta_i, phi_i).shape + (3,)``
    """
    theta_i, phi_i = np.broadcast_arrays(np.asarray(theta_i, dtype=np.float64), np.asarray(phi_i, dtype=np.float64))
    x, w = np.polynomial.legendre.leggauss(int(n))
    theta = (x + 1.0) * (np.pi / 4.0)  # nodes on [0, π/2]
    w_theta = w * (np.pi / 4.0) * np.cos(theta) * np.sin(theta)
    n_phi = 2 * int(n)
    dphi = 2.0 * np.pi / n_phi
    phi = np.arange(n_phi) * dphi
    weights = (w_theta[:, None] * dphi) * np.ones(n_phi)  # (nθ, nφ)
    flat_ti, flat_pi = theta_i.ravel(), phi_i.ravel()
    out = np.empty((flat_ti.size, 3))
    per = max(1, int(chunk) // weights.size)
    for start in range(0, flat_ti.size, per):  # bounded chunks of incidence directions, not samples
        ti, pi_ = flat_ti[start:start + per], flat_pi[start:start + per]
        wi = from_spherical(ti, pi_)[:, None, None, :]
        wo = from_spherical(theta[None, :, None], pi_[:, None, None] + phi[None, None, :])
        f = model.eval(wi, wo)
        out[start:start + per] = np.einsum("kijc,ij->kc", f, weights)
    return out.reshape(theta_i.shape + (3,))
