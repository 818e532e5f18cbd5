"""Precomputed-geometry kernels: the colour basis of a model computed from geometry cached on the data.

A kernel returns exactly what :class:`gonio.fit.layout.Basis` would get from ``model.eval`` — the
offset f₀ and the basis functions Bₖ of the colour parameters — but from cosines cached once per
dataset on :class:`gonio.fit.data.FitData`, which makes each shape-parameter evaluation a handful of
array operations. Tests check every kernel against its model's ``eval``.
"""

from __future__ import annotations

from typing import Callable

#: Registry: model name -> kernel(data, fixed, shape) -> (offset or None, [basis per colour parameter]).
KERNELS: dict[str, Callable] = {}


def kernel_for(layout) -> Callable | None:
    """The kernel of ``layout``'s model, if one exists and supports its free/fixed parameters."""
    k = KERNELS.get(layout.name)
    return k if k is not None and getattr(k, "supports", lambda L: True)(layout) else None


def _lambert(data, layout, shape):
    """Lambert: f = albedo/π (:class:`gonio.brdf.lambert.Lambert`); basis 1/π."""
    import numpy as np

    return None, [np.full(len(data), 1.0 / np.pi)]


def _microfacet(data, layout, shape):
    """Walter et al. 2007 microfacet + Lambert (:class:`gonio.brdf.microfacet.Microfacet`): bases
    kd → 1/π, ks → D(h) G2 F(wo·h) / (4 cos θi cos θo), from the model's own lobe formula
    (:func:`gonio.brdf.microfacet.ggx_spec` / :func:`~gonio.brdf.microfacet.beckmann_spec`) on the pair
    geometry cached on the data (:attr:`gonio.fit.data.FitData.pair`).

    f0 is fixed (per channel) or tied (one value, a shape parameter). Schlick's
    F = f0 + (1 − f0)(1 − cos θd)⁵ (Schlick 1994, eq. 15) is formed from the cached (1 − cos θd)⁵, and
    D G2/(4 cos θi cos θo) is kept for the last α, so a step in f0 alone costs two array operations.
    """
    return _lobe_basis(data, layout, shape, _spec(data, layout.fixed["distribution"], shape["alpha"]))


def _lobe_basis(data, layout, shape, spec):
    """Offset and colour bases of ``kd/π + ks · spec · F`` (a Lambert term and one lobe with Schlick's F of a
    tied f0 in ``shape`` or a fixed per-channel f0)."""
    import numpy as np

    from gonio.brdf.fresnel import schlick_blend

    fixed = layout.fixed
    if "f0" in shape:
        f0 = float(shape["f0"])
        if f0 != 1.0:
            spec = spec * schlick_blend(f0, _schlick_m5(data))
    else:
        f0 = np.asarray(fixed["f0"])
        if not np.all(f0 == 1.0):  # Schlick F = 1 exactly when f0 = 1
            spec = spec[:, None] * _fresnel_cache(data, f0)
    offsets = layout.__dict__.get("_lobe_offsets")
    if offsets is None:  # the fixed terms that add an offset (a non-zero fixed kd or ks), once per layout
        offsets = layout._lobe_offsets = tuple(k for k in ("kd", "ks") if k in fixed and np.any(np.asarray(fixed[k]) != 0))
    basis = {"kd": _diffuse_column(data) if "kd" in layout.colour or "kd" in offsets else None, "ks": spec}
    offset = None
    for k in offsets:
        b = basis[k] if basis[k].ndim == 2 else basis[k][:, None]
        offset = (0.0 if offset is None else offset) + np.asarray(fixed[k]) * b
    return offset, [basis[k] for k in layout.colour]


def _diffuse_column(data):
    """The Lambert term's basis 1/π at every sample (read-only), made once per dataset."""
    import numpy as np

    cache = data.__dict__.setdefault("_kernel_cache", {})
    col = cache.get("kd")
    if col is None:
        col = cache["kd"] = np.full(len(data), 1.0 / np.pi)
        col.setflags(write=False)
    return col


def _spec(data, name, alpha):
    """D G2 / (4 cos θi cos θo) of distribution ``name`` at roughness ``alpha`` (Walter et al. 2007, eq. 20
    without F): the model's lobe formula (:data:`gonio.brdf.microfacet.SPECS`) on the data's cached pair
    geometry, cached for the last few α."""
    import numpy as np

    from gonio.brdf.microfacet import SPECS, ggx_spec_den

    specs = data.__dict__.setdefault("_kernel_cache", {}).setdefault("spec", {})
    key = (name, float(alpha))
    hit = specs.get(key)
    if hit is None:
        if len(specs) >= SPEC_CACHE:  # the least recently used goes
            del specs[next(iter(specs))]
        with np.errstate(all="ignore"):  # as BRDF.eval: the formulas' guards, not warnings, handle the extremes
            if name == "ggx":  # prepared data are above the horizon, where every microfacet is visible
                hit = 1.0 / ggx_spec_den(data.pair, float(alpha))  # = ggx_spec there, one pass less
            else:
                hit = np.asarray(SPECS[name](data.pair, float(alpha)), dtype=np.float64)
    else:
        del specs[key]  # re-inserted below: the most recently used last
    specs[key] = hit
    return hit


#: Lobe values remembered per data set by :func:`_spec` (least recently used dropped): a finite-difference
#: gradient of a two-lobe sum visits each lobe's width at x and x + h while the other lobe's is unchanged, so a
#: handful must survive; on a large table each costs N doubles (a MERL table's 1.1e6: 9 MB).
SPEC_CACHE = 8


def _schlick_m5(data):
    """(1 − cos θd)⁵ of Schlick's approximation (:func:`gonio.brdf.fresnel.schlick_weight` of the pair
    geometry's cancellation-free 1 − cos θd), cached per dataset."""
    from gonio.brdf.fresnel import schlick_weight

    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "m5" not in cache:
        cache["m5"] = schlick_weight(data.pair.m)
    return cache["m5"]


def _geometry(data):
    """Cached per dataset: cos²θh, sin²θh, tan²θi, tan²θo (for the derivative :func:`_ggx_spec_dalpha`)."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "ggx" not in cache:
        p = data.pair
        cache["ggx"] = (p.hz2, p.s2h, p.si2 / p.iz2, p.so2 / p.oz2)
    return cache["ggx"]


def _fresnel_cache(data, f0):
    """Schlick F(wo·h) for fixed f0 depends only on the geometry: computed once per dataset."""
    from gonio.brdf.fresnel import schlick_blend

    key = ("fresnel", tuple(f0.tolist()))
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if key not in cache:
        cache[key] = schlick_blend(f0, _schlick_m5(data)[:, None])
    return cache[key]


def _ggx_spec_dalpha(data, alpha, floor: bool = True):
    """∂S/∂α of S = D G2 / (4 cos θi cos θo) for GGX (the α-column of the Jacobian, exact).

    From D = α²/(π (sin²θh + α² cos²θh)²) and G1(v) = 2/(1 + rᵥ), rᵥ = √(1 + α² tan²θv) (Walter et al.
    2007, eqs. 33-34): ∂ln S/∂α² = 1/α² − 2 cos²θh/(sin²θh + α² cos²θh) − Σᵥ tan²θv/(2 rᵥ (1 + rᵥ)),
    and ∂α²/∂α = 2α (0 below the roughness floor, where α is clamped). Checked against central
    differences in tests/fit/test_fast.py. ``floor=False``: at the floor itself, the derivative from above (what
    a search standing on the floor needs to leave it).
    """
    import numpy as np

    from gonio.brdf.microfacet import ALPHA_MIN

    if alpha < ALPHA_MIN or (floor and alpha == ALPHA_MIN):
        return np.zeros(len(data))
    c2h, s2h, t2i, t2o = _geometry(data)
    a2 = float(alpha) ** 2
    dlog = 1.0 / a2 - 2.0 * c2h / (s2h + a2 * c2h)
    for t2 in (t2i, t2o):
        r = np.sqrt(1.0 + a2 * t2)
        dlog -= t2 / (2.0 * r * (1.0 + r))
    return _spec(data, "ggx", alpha) * dlog * (2.0 * float(alpha))


def _microfacet_derivatives(data, layout, shape):
    """Derivatives of :func:`_microfacet`'s offset and colour bases in each shape parameter, for GGX
    (:func:`gonio.fit.gradient.basis_derivatives`): ``{name: (∂offset or None, [∂Bₖ or None per colour])}``.

    With F = f0 + (1 − f0) m⁵ (Schlick 1994, eq. 15) the lobe's basis is S(α) F: ∂/∂α = (∂S/∂α) F
    (:func:`_ggx_spec_dalpha`, exact) and, for a tied f0, ∂/∂f0 = S (1 − m⁵); the Lambert basis 1/π is constant;
    a fixed non-zero ks adds ks times the lobe's derivative to the offset."""
    import numpy as np

    from gonio.brdf.fresnel import schlick_blend

    fixed = layout.fixed
    alpha = float(shape["alpha"])
    dS = _ggx_spec_dalpha(data, alpha, floor=False)
    per = {}
    if "f0" in shape:
        f0 = float(shape["f0"])
        per["alpha"] = dS if f0 == 1.0 else dS * schlick_blend(f0, _schlick_m5(data))
        per["f0"] = _spec(data, "ggx", alpha) * (1.0 - _schlick_m5(data))
    else:
        f0 = np.asarray(fixed["f0"])
        per["alpha"] = dS if np.all(f0 == 1.0) else dS[:, None] * _fresnel_cache(data, f0)
    out = {}
    for name, d in per.items():
        off = None
        if "ks" in fixed and np.any(np.asarray(fixed["ks"]) != 0):
            off = np.asarray(fixed["ks"]) * (d if d.ndim == 2 else d[:, None])
        out[name] = (off, [d if c == "ks" else None for c in layout.colour])
    return out


_microfacet_derivatives.supports = lambda L: L.fixed.get("distribution") == "ggx"


class MicrofacetTiedF0:
    """The microfacet kernel with a tied Schlick f0 = t, written over *elementary* vectors (see
    :class:`gonio.fit.solve.ProfiledProjection`): with S = D G2/(4 cos θi cos θo) and m⁵ = (1 − cos θd)⁵,

        f_c = kd_c/π + ks_c (t S + (1 − t) S m⁵)          (Walter et al. 2007, eq. 20; Schlick 1994, eq. 15)

    so every colour basis function is T(t) · [1/π, S, S m⁵] with T affine in t. For one α the weighted
    Gram matrix of the three elementary vectors gives the projected cost at *every* f0 in O(1), which
    turns the two-parameter shape search (α, f0) into a one-parameter search in α with an exact inner
    minimization over f0 (the optimum is the joint one: min over (α, t, a) = min_α min_t min_a).

    Applies to ``microfacet`` and to the sums ``lambert+ggx`` / ``lambert+beckmann`` (Lambert albedo as kd,
    the lobe's ks, α and f0), with f0 tied and no colour held at a non-zero value.
    """

    def __init__(self, layout):
        self.roles = roles = self._roles(layout)
        self.tied = None if roles is None else roles["f0"]

    @staticmethod
    def _roles(L):
        if L.name == "microfacet":
            return {"kd": "kd", "ks": "ks", "alpha": "alpha", "f0": "f0", "distribution": L.fixed.get("distribution")}
        parts = getattr(L.cls, "PARTS", ())
        if len(parts) == 2 and parts[0][1].name == "lambert" and parts[1][1].name == "microfacet":
            d, s = parts[0][0], parts[1][0]
            return {"kd": f"{d}.albedo", "ks": f"{s}.ks", "alpha": f"{s}.alpha", "f0": f"{s}.f0",
                    "distribution": dict(parts[1][2]).get("distribution")}
        return None

    def supports(self, L) -> bool:
        """f0 tied (profiled out and in the Jacobian)."""
        r = self.roles
        return self._colours_ok(L) and L.shape == [r["alpha"], r["f0"]] and r["f0"] in L.tied

    def supports_jacobian(self, L) -> bool:
        """f0 tied, or held at 1 for every channel (F = 1: then only the Jacobian is provided)."""
        import numpy as np

        r = self.roles
        return self.supports(L) or (self._colours_ok(L) and L.shape == [r["alpha"]] and r["f0"] in L.fixed
                                    and bool(np.all(np.asarray(L.fixed[r["f0"]]) == 1.0)))

    def _colours_ok(self, L) -> bool:
        import numpy as np

        r = self.roles
        return (r is not None and r["distribution"] is not None and r["ks"] in L.colour
                and set(L.colour) <= {r["kd"], r["ks"]}
                and not any(k in L.fixed and np.any(np.asarray(L.fixed[k]) != 0) for k in (r["kd"], r["ks"])))

    def elements(self, data, L, shape_nl):
        """``[1/π, S, S m⁵]`` at α = ``shape_nl[0]`` (a float stands for a constant vector)."""
        S = _spec(data, self.roles["distribution"], float(shape_nl[0]))
        return [1.0 / 3.141592653589793, S, S * _schlick_m5(data)]

    def transform(self, L, t):
        """T(t), shape (len(t), K, 3): colour basis k = Σⱼ T[k, j] eⱼ, for an array of f0 values ``t``."""
        import numpy as np

        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        T = np.zeros((t.size, L.K, 3))
        for k, name in enumerate(L.colour):
            if name == self.roles["kd"]:
                T[:, k, 0] = 1.0
            else:
                T[:, k, 1], T[:, k, 2] = t, 1.0 - t
        return T

    def jacobian(self, data, L, colour, shape):
        """Elementary vectors ``[1/π, S, S m⁵, ∂S/∂α, ∂S/∂α m⁵]`` and coefficients C (3, 5, 3K + 2): the
        Jacobian column of parameter q in channel c is ∂f_c/∂p_q = Σⱼ C[c, j, q] eⱼ (exact for GGX; ∂S/∂α
        by central differences of S for other distributions)."""
        import numpy as np

        from gonio.brdf.microfacet import ALPHA_MIN

        r = self.roles
        name = r["distribution"]
        ia = L.shape.index(r["alpha"])
        it = L.shape.index(r["f0"]) if r["f0"] in L.shape else None  # None: f0 held at 1, F = 1
        alpha, t = float(shape[ia]), (1.0 if it is None else float(shape[it]))
        S, m5 = _spec(data, name, alpha), _schlick_m5(data)
        if name == "ggx":
            dS = _ggx_spec_dalpha(data, alpha)
        else:
            h = 1e-6 * max(alpha, 1e-3)
            up, dn = alpha + h, max(alpha - h, ALPHA_MIN)
            dS = (_spec(data, name, up) - _spec(data, name, dn)) / (up - dn)
        elems = [1.0 / np.pi, S, S * m5, dS, dS * m5]
        K = L.K
        C = np.zeros((3, 5, 3 * K + L.S))
        ks = colour[L.colour.index(r["ks"])]
        for c in range(3):
            for k, nm in enumerate(L.colour):
                if nm == r["kd"]:
                    C[c, 0, 3 * k + c] = 1.0
                else:
                    C[c, 1, 3 * k + c], C[c, 2, 3 * k + c] = t, 1.0 - t
            qa = 3 * K + ia
            C[c, 3, qa], C[c, 4, qa] = ks[c] * t, ks[c] * (1.0 - t)
            if it is not None:
                C[c, 1, 3 * K + it], C[c, 2, 3 * K + it] = ks[c], -ks[c]
        if it is None:  # F = 1: the m⁵ vectors have zero coefficients
            return [elems[0], elems[1], elems[3]], C[:, [0, 1, 3], :]
        return elems, C


#: Registry: model name -> profile kernel class (an affine tied parameter profiled out exactly).
PROFILES: dict[str, type] = {"microfacet": MicrofacetTiedF0, "lambert+ggx": MicrofacetTiedF0,
                             "lambert+beckmann": MicrofacetTiedF0}


def _kernel_if(layout, test: str):
    cls = PROFILES.get(layout.name)
    if cls is None or getattr(layout, "links", None):  # linked colours (gonio.fit.layout.linked_lobes): no profile
        return None
    p = cls(layout)
    return p if getattr(p, test)(layout) else None


def jacobian_for(layout):
    """A kernel with an exact ``jacobian(data, L, colour, shape)`` for ``layout`` (see
    :meth:`MicrofacetTiedF0.supports_jacobian`), else None."""
    return _kernel_if(layout, "supports_jacobian")


def profile_for(layout):
    """The profile kernel of ``layout`` (:data:`PROFILES`, bound to it) if it supports its free/fixed/tied
    parameters, else None."""
    return _kernel_if(layout, "supports")


def _gtr(data, layout, shape):
    """Burley 2012's GTR lobe + Lambert (:class:`gonio.brdf.gtr.GTR`) on cached geometry: bases kd → 1/π,
    ks → D_GTR(θh; α, γ) G2 F / (4 cos θi cos θo), the model's lobe formula (:func:`gonio.brdf.gtr.gtr_spec`)
    on the pair geometry cached on the data, with Schlick's F for a tied or fixed f0 (Schlick 1994, eq. 15).
    Equality with the model is a test (tests/fit/test_real_data.py)."""
    import numpy as np

    from gonio.brdf.gtr import gtr_norm, gtr_spec

    alpha, gamma = float(shape["alpha"]), float(shape["gamma"])
    with np.errstate(all="ignore"):
        spec = gtr_spec(data.pair, alpha, gamma, gtr_norm(alpha, gamma))
    return _lobe_basis(data, layout, shape, spec)


def _oren_nayar(data, layout, shape):
    """Oren & Nayar 1994's qualitative model (:class:`gonio.brdf.oren_nayar.OrenNayar`, eq. 30): basis of the
    albedo (A(σ) + B(σ) t)/π with the geometric term t = max(0, wi⊥·wo⊥)/max(cos θi, cos θo) cached per dataset."""
    a, b = _oren_nayar_ab(float(shape["sigma"]))
    return None, [(a + b * _oren_nayar_term(data)) / 3.141592653589793]


def _oren_nayar_ab(sigma):
    """A = 1 − 0.5 σ²/(σ² + 0.33) and B = 0.45 σ²/(σ² + 0.09) (Oren & Nayar 1994, eq. 30)."""
    s2 = sigma * sigma
    return 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)


def _oren_nayar_term(data):
    """max(0, wi_x wo_x + wi_y wo_y) / max(cos θi, cos θo), the model's own expression, once per dataset."""
    import numpy as np

    from gonio.brdf.microfacet import _tiny

    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "oren_nayar" not in cache:
        wi, wo = data.wi, data.wo
        p = np.maximum(wi[:, 0] * wo[:, 0] + wi[:, 1] * wo[:, 1], 0.0)
        cache["oren_nayar"] = p / np.maximum(np.maximum(wi[:, 2], wo[:, 2]), _tiny(wi))
    return cache["oren_nayar"]


def _oren_nayar_derivatives(data, layout, shape):
    """∂/∂σ of :func:`_oren_nayar`'s basis: (A' + B' t)/π with A' = −0.33 σ/(σ² + 0.33)² and
    B' = 0.081 σ/(σ² + 0.09)² (derivatives of eq. 30's A and B)."""
    sigma = float(shape["sigma"])
    s2 = sigma * sigma
    da, db = -0.33 * sigma / (s2 + 0.33) ** 2, 0.081 * sigma / (s2 + 0.09) ** 2
    return {"sigma": (None, [(da + db * _oren_nayar_term(data)) / 3.141592653589793])}


def _nonzero(value) -> bool:
    """Whether a held colour adds an offset to the basis (any channel not 0)."""
    import numpy as np

    return bool(np.any(np.asarray(value, dtype=np.float64) != 0.0))


def _ward(data, layout, shape):
    """Ward 1992's anisotropic model (:class:`gonio.brdf.ward.Ward`, eq. 5a) on cached geometry: bases kd → 1/π,
    ks → exp(−(h_x²/α_x² + h_y²/α_y²)/h_z²) / (4π α_x α_y √(cos θi cos θo)) — the model's own expression, term for
    term, on the half vector and √(cos θi cos θo) cached per dataset (:func:`_ward_geometry`), where the model's
    evaluation formed the half vector and checked its inputs twice per shape (once per colour)."""
    import numpy as np

    from gonio.brdf.microfacet import clamp_alpha

    hx, hy, hz2, root = _ward_geometry(data)
    ax, ay = clamp_alpha(float(shape["alpha_x"])), clamp_alpha(float(shape["alpha_y"]))
    with np.errstate(all="ignore"):  # as BRDF.eval
        e = ((hx / ax) ** 2 + (hy / ay) ** 2) / hz2
        spec = np.exp(-e) / (4.0 * np.pi * ax * ay * root)
    return None, [_diffuse_column(data) if name == "kd" else spec for name in layout.colour]


def _ward_geometry(data):
    """h_x, h_y, max(h_z², tiny) and √max(cos θi cos θo, tiny) of :class:`gonio.brdf.ward.Ward` (its half vector and
    guards), once per dataset."""
    import numpy as np

    from gonio.brdf.microfacet import _tiny, half_vector

    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "ward" not in cache:
        wi, wo = data.wi, data.wo
        h = half_vector(wi, wo)
        tiny = _tiny(wi)
        cache["ward"] = (np.ascontiguousarray(h[:, 0]), np.ascontiguousarray(h[:, 1]),
                         np.maximum(h[:, 2] ** 2, tiny), np.sqrt(np.maximum(wi[:, 2] * wo[:, 2], tiny)))
    return cache["ward"]


_oren_nayar.supports = lambda L: L.colour == ["albedo"] and L.shape == ["sigma"]
_oren_nayar.derivatives = _oren_nayar_derivatives
_oren_nayar_derivatives.supports = lambda L: True
_gtr.supports = lambda L: {"alpha", "gamma"} <= set(L.shape) and ("f0" in L.fixed or "f0" in L.shape)
_microfacet.supports = lambda L: L.shape in (["alpha"], ["alpha", "f0"]) and ("f0" in L.fixed or "f0" in L.shape)
_lambert.supports = lambda L: L.colour == ["albedo"]
_microfacet.derivatives = _microfacet_derivatives
_ward.supports = lambda L: (L.shape == ["alpha_x", "alpha_y"] and set(L.colour) <= {"kd", "ks"}  # no offset:
                            and all(k in L.colour or not _nonzero(L.fixed.get(k, 0.0)) for k in ("kd", "ks")))
KERNELS.update({"lambert": _lambert, "microfacet": _microfacet, "gtr": _gtr, "oren-nayar": _oren_nayar, "ward": _ward})

from gonio.fit.kernels_abc import KERNELS_ABC  # noqa: E402  (models for real measurements, issue 14)

KERNELS.update(KERNELS_ABC)
