"""A conductor under a thin dielectric coat (lacquer, oxide) on the data-driven microfacet model of Dupuy et al. 2015
(issue 29).

Why. Some MERL metals reflect like a dielectric towards grazing: alum-bronze's table wants a Fresnel factor rising from
F(0) ≈ 0.07–0.15 to 1 (the published ABC fit takes a dielectric index 2.24 for it, brass 2.70, nickel 5.44), which no
bare metal does — a conductor's F stays flat until grazing (Palik 1985). A thin dielectric layer over the metal does
exactly this: its own reflection rises from ((n − 1)/(n + 1))² ≈ 0.04 to 1, while the light that reaches the metal and
comes back is cut by the coat's transmission (1 − F_d)², which falls to 0 at grazing, and by the layer's absorption.

The model composes published pieces: Weidlich & Wilkie 2007's layered microfacet surface (A. Weidlich, A. Wilkie,
"Arbitrarily layered micro-facet surfaces", GRAPHITE 2007, §3–4: the top interface's reflection plus the base's at the
refracted direction, times the two transmissions and the layer's absorption, one bounce in the layer) with a layer thin
against the roughness, so both interfaces share each microfacet's normal and the layer is a Fresnel factor of θd
alone (:func:`thin_coat_fresnel`); the tabulated D and its Smith G1 of Dupuy et al. 2015 (:class:`gonio.brdf.dupuy.
Dupuy2015`); the exact dielectric (:func:`gonio.brdf.fresnel.dielectric_core`) and conductor
(:func:`gonio.brdf.fresnel.conductor_core`) Fresnel equations. Its fit: :mod:`gonio.fit.dupuy_coated`.

Rendering: pbrt-v4's ``coatedconductor`` (interface.eta = n, conductor.eta / conductor.k, one roughness for both
interfaces, the layer's absorption through ``thickness`` and ``albedo`` 0) has the same structure, sampled
stochastically with the inter-reflections this model leaves out; Mitsuba 3 has no coated conductor (its ``principled``
BSDF with ``metallic`` 1 and a ``clearcoat`` is the nearest).
"""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import Param
from gonio.brdf.dupuy import Dupuy2015Conductor
from gonio.brdf.fresnel import conductor_core, dielectric_core

__all__ = ["Dupuy2015Coated", "thin_coat_fresnel", "COAT_N_MIN", "COAT_N_MAX", "BASE_EDGE_MIN"]

#: Range of the coat's refractive index: lacquers, resins and glasses 1.3–1.7, thin oxides up to ~2.0 (Al₂O₃ 1.77;
#: Palik 1985): the fit's bounds, and what the realdata benchmark calls a physical coat.
COAT_N_MIN, COAT_N_MAX = 1.3, 2.0
#: Lowest Gulbrandsen edge tint of the metal under the coat (:func:`gonio.brdf.fresnel.gulbrandsen_index`): with
#: g ≥ 0.2 its extinction k is at least 0.94 for every F(0) in [0.5, 0.99] — an absorbing conductor, never the
#: dielectric of that F(0) (g = 0: k = 0) which F(0) ≥ 0.5 alone admits. Under a coat the metal is seen only through
#: t F_c, and its index trades off with t: on alum-bronze a fit free to take g = 0 reached k = 0 in two channels with
#: the same errors as this bound's k > 2 (issue 29).
BASE_EDGE_MIN = 0.2


def thin_coat_fresnel(cos_d, n, eta, k, t):
    """The Fresnel factor of a microfacet whose conductor (index η + i k in air) carries a thin conformal dielectric coat
    of index n and round-trip transmittance ``t`` at normal incidence (Weidlich & Wilkie 2007, §3–4, with the two
    interfaces sharing each microfacet's normal: a layer thin against the roughness, as an oxide or a lacquer film;
    one bounce in the layer, incoherent — no thin-film interference):

        F(θd) = F_d(θd; n) + (1 − F_d(θd; n))² · t^(1/cos θd') · F_c(θd'; (η + i k)/n),   sin θd' = sin θd / n,

    F_d the exact dielectric reflectance (:func:`gonio.brdf.fresnel.dielectric_core`), F_c the conductor's
    (:func:`gonio.brdf.fresnel.conductor_core`) against the coat, t^(1/cos θd') the layer's Beer–Lambert absorption
    along the refracted path (down and up). n = 1, t = 1 is the bare conductor; t = 0 the dielectric alone.
    ``cos_d`` (N,) in [0, 1]; ``n`` a scalar; ``eta``, ``k``, ``t`` scalars or arrays broadcasting against each other
    (RGB (3,): the result is (N, 3); a scan's (G, 1), (G, 1), (1, T): (N, G, T), the conductor evaluated on (N, G))."""
    c = np.clip(np.asarray(cos_d, dtype=np.float64), 0.0, 1.0)
    eta, k, t = (np.asarray(v, dtype=np.float64) for v in (eta, k, t))
    c = c.reshape(c.shape + (1,) * max(eta.ndim, k.ndim, t.ndim))
    fd = dielectric_core(c, n)
    ct = np.sqrt(np.maximum(1.0 - (1.0 - c * c) / (n * n), 0.0))  # cos θd' > 0: no total reflection entering the coat
    with np.errstate(divide="ignore"):
        absorb = np.where(t > 0.0, np.exp(np.log(np.maximum(t, 1e-300)) / np.maximum(ct, 1e-300)), 0.0)
    return fd + (1.0 - fd) ** 2 * absorb * conductor_core(ct, eta / n, k / n)


class Dupuy2015Coated(Dupuy2015Conductor):
    """:class:`gonio.brdf.dupuy.Dupuy2015Conductor` under a thin dielectric coat: the tabulated D and its Smith G1 of
    Dupuy et al. 2015, and the Fresnel factor ks · F(θd) of :func:`thin_coat_fresnel` — the coat's own reflection
    (index ``n``, one for R, G, B) plus the conductor (η + i k per channel, F(0) in air ≥ 0.5 and k ≥ 0.94 as fitted,
    :data:`BASE_EDGE_MIN`: a metal) seen through
    it, dimmed by the layer's round-trip transmittance ``t`` (per channel: an oxide's or a tinted lacquer's colour).
    n = 1, t = 1 would be the bare conductor; n's range is a coat's (:data:`COAT_N_MIN`–:data:`COAT_N_MAX`). pbrt-v4's
    ``coatedconductor`` (interface.eta = n, conductor.eta/k, one roughness for both) renders the same structure."""

    name = "dupuy2015-coated"
    PARAMS = {
        **Dupuy2015Conductor.PARAMS,
        "n": Param("scalar", COAT_N_MIN, COAT_N_MAX, 1.5, doc="the coat's refractive index (one for R, G, B)"),
        "t": Param("rgb", 0.0, 1.0, 1.0, doc="the coat's round-trip transmittance at normal incidence, per RGB channel"),
    }

    def fresnel_at(self, cos_d) -> np.ndarray:
        """ks · F(θd) of :func:`thin_coat_fresnel`, shape ``cos_d.shape + (3,)``."""
        p = self._params
        return np.asarray(p["ks"]) * thin_coat_fresnel(cos_d, float(p["n"]), np.asarray(p["eta"]), np.asarray(p["k"]),
                                                       np.asarray(p["t"]))

    def stand_in(self):
        """As :meth:`Dupuy2015Conductor.stand_in`, with the coated Fresnel factor at normal incidence as Schlick f0."""
        from gonio.brdf import make
        from gonio.brdf.dupuy import closest_ggx_alpha

        alpha = closest_ggx_alpha(self._ndf)
        f0 = np.clip(self.fresnel_at(np.ones(1))[0] / np.maximum(np.asarray(self._params["ks"]), 1e-300), 0.0, 1.0)
        return (make("microfacet", kd=self._params["kd"], ks=self._params["ks"], alpha=alpha, f0=f0),
                f"{self.name} (tabulated D, coated conductor) has no counterpart: exported as the GGX microfacet closest "
                f"to its D (alpha {alpha:.3g}, Schlick f0 its coated Fresnel at normal incidence)")
