"""Energy conservation of fitted parameters: the directional albedo must not exceed 1 at any θi.

ρ(θi) = ∫ f(wi, wo) cos θo dωo (Nicodemus et al. 1977; :func:`gonio.brdf.albedo.directional_albedo`) is
computed at the incidence angles :data:`THETAS_DEG` with :data:`NODES` Gauss-Legendre nodes in θo (2×
in φo). A lobe narrower than the node spacing (α ≲ 0.01) is integrated to ~10-20 %, so for models
whose albedo is bounded analytically the bound is used as well: a normalized microfacet lobe (GGX,
Beckmann, GTR with the Smith G, Walter et al. 2007; a tabulated D with the Smith G1 it implies, Dupuy et al.
2015) reflects at most ks·max F ≤ ks, so ρ ≤ kd + Σ ks (kd + max F for the tabulated model) per channel.
"""

from __future__ import annotations

import numpy as np

__all__ = ["THETAS_DEG", "NODES", "TOLERANCE", "albedo_check"]

#: Incidence angles at which the albedo is checked (degrees).
THETAS_DEG = (0.0, 20.0, 40.0, 60.0, 75.0, 85.0)
#: Gauss-Legendre nodes in θo.
NODES = 128
#: ρ above 1 + TOLERANCE is a violation (quadrature error of broad lobes is ~1e-3).
TOLERANCE = 0.01


def _analytic_bound(model) -> np.ndarray | None:
    """kd + Σ ks per channel where every term is a Lambertian or a normalized microfacet lobe, else None."""
    from gonio.brdf.dupuy import Dupuy2015
    from gonio.brdf.gtr import GTR
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.lobes import Sum
    from gonio.brdf.microfacet import Microfacet

    parts = model.parts if isinstance(model, Sum) else (model,)
    total = np.zeros(3)
    for p in parts:
        if isinstance(p, Lambert):
            total = total + np.asarray(p.albedo)
        elif isinstance(p, Microfacet) or (isinstance(p, GTR) and p.gamma == 2.0):
            total = total + np.asarray(p.kd) + np.asarray(p.ks)
        elif isinstance(p, Dupuy2015):  # normalized D with its own Smith G1 (Dupuy et al. 2015): ρ ≤ kd + max F
            f_max = np.asarray(p.ks) if "ks" in p.PARAMS else np.asarray(p.fresnel).max(axis=0)  # conductor: F ≤ 1
            total = total + np.asarray(p.kd) + f_max
        else:
            return None
    return total


def albedo_check(model) -> dict:
    """``{"albedo_max": ρ_max (max over channels and THETAS_DEG), "theta_deg": where, "ok": bool}``."""
    from gonio.brdf.albedo import directional_albedo

    rho = directional_albedo(model, np.radians(THETAS_DEG), n=NODES)  # (len(THETAS_DEG), 3)
    j, c = np.unravel_index(int(np.argmax(rho)), rho.shape)
    rmax = float(rho[j, c])
    bound = _analytic_bound(model)
    if bound is not None and float(bound.max()) < rmax:  # the quadrature overshoots a lobe it cannot resolve
        return {"albedo_max": float(bound.max()), "theta_deg": float(THETAS_DEG[j]), "ok": bool(bound.max() <= 1.0 + 1e-12),
                "bound": "kd + ks (normalized microfacet lobes)"}
    return {"albedo_max": rmax, "theta_deg": float(THETAS_DEG[j]), "ok": bool(rmax <= 1.0 + TOLERANCE)}
