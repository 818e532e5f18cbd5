"""A data-driven microfacet BRDF: a tabulated isotropic normal distribution, the Smith shadowing it implies,
a tabulated Fresnel term and a diffuse floor (Dupuy et al. 2015).

J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF Parameters
from Arbitrary Materials with Power Iterations", Computer Graphics Forum 34(4) (EGSR 2015). The model is

    f(wi, wo) = kd/π + F(θd) · D(θh) · G1(θi) G1(θo) / (4 cos θi cos θo)

* D(θh) (1/sr): the normal distribution of an isotropic microsurface, tabulated at :data:`N_NDF` nodes
  θ_j = (π/2)·(j/(n − 1))² (dense near the normal, where measured metals have razor-thin peaks; the
  square-root mapping of the MERL table's θh axis, Matusik et al. 2003) and linear between them;
  normalized so that the projected microfacet area is the macro-surface, ∫ D(m) (m·n) dm = 1
  (Dupuy et al. 2015 §3, eq. 2).
* G1(θ): Smith's masking derived from D itself, not from a closed form — the projected area of the visible
  microsurface equals that of the macro-surface, G1(k) = cos θk / ∫ max(0, k·m) D(m) dm (Dupuy et al. 2015
  eq. 4; Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014,
  eq. 13 with the Smith microsurface profile); the azimuthal integral of max(0, k·m) over φ has the closed
  form of :func:`projected_kernel`, so A(θk) = ∫ max(0, k·m) D dm is a one-dimensional quadrature.
  Shadowing and masking are combined separably, G2 = G1(θi) G1(θo) (Heitz 2014 §5.1, the form Dupuy et al.
  use away from back-scattering).
* F(θd): the Fresnel factor, tabulated per RGB channel at :data:`N_FRESNEL` nodes of θd uniform in
  [0, π/2] and linear between them (it carries the specular colour; with D normalized it is the
  microfacets' reflectance, in [0, 1]).
* kd: the diffuse albedo (Lambert), per channel.

How the tables are fitted to measured samples (the power iteration on the back-scattering relation, then
alternating linear least squares) is :mod:`gonio.fit.dupuy`. Mitsuba 3 has no microfacet plugin with a
tabulated NDF; ``gonio fit --mitsuba --approx`` writes the closest analytic material and prints its error
(:mod:`gonio.io.approx`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from gonio.brdf.base import BRDF, Param

__all__ = ["Dupuy2015", "Dupuy2015Conductor", "N_NDF", "N_FRESNEL", "ndf_nodes", "fresnel_nodes", "hat_weights", "projected_kernel",
           "projected_area", "normalization", "smith_g1_table", "G1_NODES"]

#: Nodes of the tabulated D (default size of a fit).
N_NDF = 90
#: Nodes of the tabulated Fresnel factor (default size of a fit).
N_FRESNEL = 10
#: Nodes of the quadrature over θm (uniform in √(θm/(π/2)), as D's nodes).
_QUAD = 1024
#: Range of the complex index of the conductor variant (:class:`Dupuy2015Conductor`): real part, extinction — what
#: Gulbrandsen's (F(0), edge tint) reach with F(0) in [0.5, 0.99] (:func:`gonio.brdf.fresnel.gulbrandsen_index`).
ETA_MIN, ETA_MAX, K_MAX = 0.005, 400.0, 200.0
#: Nodes θk (uniform in [0, π/2]) at which G1 is tabulated and interpolated.
G1_NODES = 256


def ndf_nodes(n: int) -> np.ndarray:
    """θh of D's ``n`` nodes: (π/2)·(j/(n − 1))², j = 0 … n − 1 (module docstring)."""
    return 0.5 * np.pi * np.linspace(0.0, 1.0, n) ** 2


def fresnel_nodes(n: int) -> np.ndarray:
    """θd of the Fresnel table's ``n`` nodes: uniform in [0, π/2]."""
    return np.linspace(0.0, 0.5 * np.pi, n)


def hat_weights(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation on ``n`` nodes at positions ``x`` in node units ([0, n − 1], clipped):
    ``(j, t)`` with value = (1 − t)·v[j] + t·v[j + 1]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, n - 1.0)
    j = np.minimum(x.astype(np.intp), n - 2)
    return j, x - j


def ndf_position(theta_h: np.ndarray, n: int) -> np.ndarray:
    """Position of θh in node units of D's table: (n − 1)·√(θh/(π/2))."""
    return (n - 1) * np.sqrt(np.clip(theta_h, 0.0, 0.5 * np.pi) / (0.5 * np.pi))


def projected_kernel(theta_k: np.ndarray, theta_m: np.ndarray) -> np.ndarray:
    """I(θk, θm) = ∫₀^{2π} max(0, cos θk cos θm + sin θk sin θm cos φ) dφ, in closed form (outer product of
    the two arrays): with a = cos θk cos θm, b = sin θk sin θm ≥ 0, I = 2πa where a ≥ b, 0 where a ≤ −b,
    else 2(a φ₀ + √(b² − a²)) with φ₀ = arccos(−a/b) (the integrand is positive for |φ| < φ₀).
    ∫ max(0, k·m) D(m) dm = ∫ D(θm) sin θm I(θk, θm) dθm (Dupuy et al. 2015 eq. 4's projected area)."""
    tk = np.asarray(theta_k, dtype=np.float64)[:, None]
    tm = np.asarray(theta_m, dtype=np.float64)[None, :]
    a = np.cos(tk) * np.cos(tm)
    b = np.sin(tk) * np.sin(tm)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = np.arccos(np.clip(-a / np.where(b > 0, b, 1.0), -1.0, 1.0))
        partial = 2.0 * (a * phi0 + np.sqrt(np.maximum(b * b - a * a, 0.0)))
    return np.where(a >= b, 2.0 * np.pi * a, np.where(a <= -b, 0.0, partial))


@lru_cache(maxsize=8)
def _quadrature(n: int):
    """Quadrature of ∫₀^{π/2} g(θ) dθ on :data:`_QUAD` points uniform in u = √(θ/(π/2)) (trapezoid in u,
    dθ = π u du) for functions tabulated on ``n`` nodes of D: ``(theta, weights, interpolation matrix)``."""
    u = np.linspace(0.0, 1.0, _QUAD)
    theta = 0.5 * np.pi * u * u
    w = np.full(_QUAD, u[1] - u[0]) * np.pi * u
    w[0] *= 0.5
    w[-1] *= 0.5
    j, t = hat_weights(ndf_position(theta, n), n)
    interp = np.zeros((_QUAD, n))
    interp[np.arange(_QUAD), j] += 1.0 - t
    interp[np.arange(_QUAD), j + 1] += t
    return theta, w, interp


@lru_cache(maxsize=8)
def _area_matrix(n: int) -> np.ndarray:
    """Matrix P (G1_NODES × n) with A(θk) = P @ D for D tabulated on ``n`` nodes (:func:`projected_area`)."""
    theta, w, interp = _quadrature(n)
    tk = np.linspace(0.0, 0.5 * np.pi, G1_NODES)
    return (projected_kernel(tk, theta) * (w * np.sin(theta))[None, :]) @ interp


@lru_cache(maxsize=8)
def _norm_vector(n: int) -> np.ndarray:
    """Vector v with ∫ D(m)(m·n) dm = v @ D (2π ∫ D cos θ sin θ dθ)."""
    theta, w, interp = _quadrature(n)
    return (2.0 * np.pi * w * np.cos(theta) * np.sin(theta)) @ interp


def projected_area(ndf: np.ndarray) -> np.ndarray:
    """A(θk) = ∫ max(0, k·m) D(m) dm at the :data:`G1_NODES` θk uniform in [0, π/2] (Dupuy et al. 2015 eq. 4)."""
    ndf = np.asarray(ndf, dtype=np.float64)
    return _area_matrix(ndf.shape[0]) @ ndf


def normalization(ndf: np.ndarray) -> float:
    """∫ D(m) (m·n) dm of a tabulated D (1 for a normalized one, Dupuy et al. 2015 eq. 2)."""
    ndf = np.asarray(ndf, dtype=np.float64)
    return float(_norm_vector(ndf.shape[0]) @ ndf)


def smith_g1_table(ndf: np.ndarray) -> np.ndarray:
    """Smith G1(θk) = cos θk / A(θk) at :data:`G1_NODES` θk uniform in [0, π/2], clipped to [0, 1]
    (Dupuy et al. 2015 eq. 4; D normalized first so that G1(0) = 1)."""
    ndf = np.asarray(ndf, dtype=np.float64)
    norm = normalization(ndf)
    area = projected_area(ndf / norm) if norm > 0 else np.zeros(G1_NODES)
    ck = np.cos(np.linspace(0.0, 0.5 * np.pi, G1_NODES))
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(area > 0, ck / area, 1.0)
    return np.clip(g, 0.0, 1.0)


def interp_g1(table: np.ndarray, cos_theta: np.ndarray) -> np.ndarray:
    """G1 at directions of cosine ``cos_theta`` from :func:`smith_g1_table`'s table (linear in θ)."""
    theta = np.arccos(np.clip(cos_theta, 0.0, 1.0))
    j, t = hat_weights(theta / (0.5 * np.pi) * (G1_NODES - 1), G1_NODES)
    return (1.0 - t) * table[j] + t * table[j + 1]


def _default_ndf() -> tuple[float, ...]:
    """GGX with α = 0.1 (Walter et al. 2007 eq. 33) at the :data:`N_NDF` nodes: the default D of a model made by name."""
    c2 = np.cos(ndf_nodes(N_NDF)) ** 2
    return tuple((0.01 / (np.pi * (c2 * (0.01 - 1.0) + 1.0) ** 2)).tolist())


class Dupuy2015(BRDF):
    """Data-driven microfacet BRDF of Dupuy et al. 2015 (module docstring): kd/π + F(θd) D(θh) G1 G1 / (4 cos cos),
    D and F tabulated. Build one by fitting (``gonio.fit(data, "dupuy2015")``, :mod:`gonio.fit.dupuy`)."""

    name = "dupuy2015"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ndf": Param("table", 0.0, np.inf, _default_ndf(), doc=f"normal distribution D(theta_h) (1/sr) at nodes (pi/2)(j/(n-1))^2, "
                                               f"normalized to a projected area of 1 (a fit has {N_NDF}; default GGX alpha 0.1)"),
        "fresnel": Param("table", 0.0, 1.0, ((0.04,) * 3,) * N_FRESNEL, cols=3,
                         doc=f"Fresnel factor F(theta_d) per RGB channel at nodes uniform in [0, pi/2] "
                             f"(a fit has {N_FRESNEL}; default 0.04, a dielectric's)"),
    }

    def _validate(self) -> None:
        from gonio.errors import ConfigError

        norm = normalization(self._params["ndf"])
        if not norm > 0:
            raise ConfigError(f"{self.name}.ndf: the distribution is zero everywhere (its projected area must be > 0)")
        # derived once: D normalized (a table written by hand need not be) and its Smith G1
        object.__setattr__(self, "_ndf", np.asarray(self._params["ndf"], dtype=np.float64) / norm)
        object.__setattr__(self, "_g1", smith_g1_table(self._ndf))

    def _astype(self, dtype):
        twin = super()._astype(dtype)
        for k in ("_ndf", "_g1"):
            object.__setattr__(twin, k, self.__dict__[k])
        return twin

    def parts(self, cos_i, cos_o, cos_h, cos_d):
        """``(diffuse (3,), F (N, 3), D (N,), G2 (N,))`` at the pairs of the given cosines (the fit uses
        the same evaluation)."""
        n = self._ndf.shape[0]
        j, t = hat_weights(ndf_position(np.arccos(np.clip(cos_h, -1.0, 1.0)), n), n)
        d = (1.0 - t) * self._ndf[j] + t * self._ndf[j + 1]
        fr = np.asarray(self._params["fresnel"], dtype=np.float64)
        m = fr.shape[0]
        k, s = hat_weights(np.arccos(np.clip(cos_d, 0.0, 1.0)) / (0.5 * np.pi) * (m - 1), m)
        f = (1.0 - s)[:, None] * fr[k] + s[:, None] * fr[k + 1]
        g = interp_g1(self._g1, cos_i) * interp_g1(self._g1, cos_o)
        return np.asarray(self._params["kd"], dtype=np.float64) / np.pi, f, d, g

    def _eval(self, wi, wo):
        shape = wi.shape[:-1]
        a = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        b = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        ci, co = a[:, 2], b[:, 2]
        s = a + b
        norm = np.sqrt(np.einsum("ij,ij->i", s, s))
        safe = np.where(norm > 0, norm, 1.0)
        cos_h, cos_d = (ci + co) / safe, 0.5 * norm
        diffuse, f, d, g = self.parts(ci, co, cos_h, cos_d)
        den = 4.0 * np.maximum(ci * co, 1e-300)
        spec = f * (d * g / den)[:, None]
        out = diffuse[None, :] + np.where((ci > 0) & (co > 0), 1.0, 0.0)[:, None] * spec
        return out.reshape(shape + (3,)).astype(wi.dtype, copy=False)

    def stand_in(self):
        """The closest analytic microfacet material, for renderers without a tabulated NDF (Mitsuba 3, pbrt-v4,
        glTF; :func:`gonio.io.approx.closest_lobes`): ``microfacet`` (GGX, Smith G) with this kd, the Fresnel
        table's normal-incidence row as f0 (Schlick) and the α of :func:`closest_ggx_alpha`. ``(model, reason)``."""
        from gonio.brdf import make

        alpha = closest_ggx_alpha(self._ndf)
        f0 = np.clip(np.asarray(self._params["fresnel"], dtype=np.float64)[0], 0.0, 1.0)
        return (make("microfacet", kd=self._params["kd"], ks=1.0, alpha=alpha, f0=f0),
                f"{self.name} (tabulated D) has no counterpart: exported as the GGX microfacet closest to its D "
                f"(alpha {alpha:.3g}, f0 its Fresnel at normal incidence)")


def closest_ggx_alpha(ndf: np.ndarray) -> float:
    """The α whose GGX D (Walter et al. 2007 eq. 33) is closest to a tabulated D in the projected microfacet
    area: min over α of ∫ (D_GGX − D)² cos²θ sin θ dθ (bounded scalar search in log α, 10⁻⁴ … 1)."""
    from scipy.optimize import minimize_scalar

    ndf = np.asarray(ndf, dtype=np.float64)
    theta, w, interp = _quadrature(ndf.shape[0])
    d = interp @ ndf
    c2 = np.cos(theta) ** 2
    wt = w * c2 * np.sin(theta)

    def cost(log_a):
        a2 = np.exp(2 * log_a)
        ggx = a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)
        return float(np.sum(wt * (ggx - d) ** 2))

    res = minimize_scalar(cost, bounds=(np.log(1e-4), 0.0), method="bounded", options={"xatol": 1e-4})
    return float(np.exp(res.x))

class Dupuy2015Conductor(Dupuy2015):
    """:class:`Dupuy2015` whose Fresnel factor is a conductor's: ks · F(θd; η + ik) per RGB channel, the exact
    unpolarized Fresnel reflectance of a complex index (:func:`gonio.brdf.fresnel.conductor`; Born & Wolf
    §14.2, pbrt-v4 §9.3 ``FrComplex``) instead of a table — a metal's parameters stay physical (its
    normal-incidence reflectance ((η − 1)² + k²)/((η + 1)² + k²) is what a metal has) while ``ks`` carries
    the lobe's measured scale (1 for an ideal, fully reflecting surface; a table's absolute calibration)."""

    name = "dupuy2015-conductor"
    PARAMS = {
        "kd": Dupuy2015.PARAMS["kd"],
        "ndf": Dupuy2015.PARAMS["ndf"],
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular scale, per RGB channel (1: every microfacet reflects F)"),
        "eta": Param("rgb", ETA_MIN, ETA_MAX, 0.2, doc="real part of the complex index of refraction, per RGB channel"),
        "k": Param("rgb", 0.0, K_MAX, 3.0, doc="extinction coefficient (imaginary part of the index), per RGB channel"),
    }

    def fresnel_at(self, cos_d) -> np.ndarray:
        """ks · F_conductor(θd; η, k), shape ``cos_d.shape + (3,)``."""
        from gonio.brdf.fresnel import conductor

        return np.asarray(self._params["ks"]) * conductor(cos_d, np.asarray(self._params["eta"]),
                                                          np.asarray(self._params["k"]))

    def parts(self, cos_i, cos_o, cos_h, cos_d):
        n = self._ndf.shape[0]
        j, t = hat_weights(ndf_position(np.arccos(np.clip(cos_h, -1.0, 1.0)), n), n)
        d = (1.0 - t) * self._ndf[j] + t * self._ndf[j + 1]
        g = interp_g1(self._g1, cos_i) * interp_g1(self._g1, cos_o)
        return np.asarray(self._params["kd"], dtype=np.float64) / np.pi, self.fresnel_at(cos_d), d, g

    def stand_in(self):
        """As :meth:`Dupuy2015.stand_in`, with ks and the conductor's normal-incidence reflectance as Schlick f0."""
        from gonio.brdf import make

        from gonio.brdf.fresnel import conductor

        alpha = closest_ggx_alpha(self._ndf)
        f0 = conductor(np.ones(1), np.asarray(self._params["eta"]), np.asarray(self._params["k"]))[0]
        return (make("microfacet", kd=self._params["kd"], ks=self._params["ks"], alpha=alpha, f0=f0),
                f"{self.name} (tabulated D) has no counterpart: exported as the GGX microfacet closest to its D "
                f"(alpha {alpha:.3g}, Schlick f0 its conductor Fresnel at normal incidence)")
