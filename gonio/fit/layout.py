"""Parameter layout of a model for fitting, and the linear structure of its colour parameters.

Every :class:`gonio.brdf.BRDF` declares ``PARAMS``. For fitting: ``rgb`` parameters are fitted per
channel (3 values), ``scalar`` (shape) parameters are shared across R, G, B, ``choice`` parameters are
fixed. Most models are *affine in their colour parameters*: f = f₀(s) + Σₖ aₖ Bₖ(s), with the shape
parameters s. :class:`Basis` checks that numerically and evaluates f₀ and Bₖ, so the colours can be
solved in closed form for each shape (variable projection, Golub & Pereyra 1973).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from gonio.brdf import MODELS, BRDF
from gonio.brdf.base import Param
from gonio.errors import ConfigError, GonioError

CHANNELS = ("r", "g", "b")


def model_class(name: str) -> type[BRDF]:
    """The model class registered as ``name``, or the lobe sum it names (``"lambert+2ggx"``)."""
    from gonio.brdf.lobes import is_sum_name, lobe_sum

    if name in MODELS:
        return MODELS[name]
    if is_sum_name(name):
        try:
            return lobe_sum(name)
        except ConfigError as exc:
            raise ConfigError(f"--model: {exc}") from None
    raise ConfigError.field("--model", "model", name, f"unknown model; known: {', '.join(sorted(MODELS))}")


def resolve_fixed(cls: type[BRDF], fixed: dict, source: str = "--fix") -> dict:
    """Held parameters named as ``gonio fit`` prints them, mapped onto ``cls``'s parameters.

    * a full name (``lobe1.f0``, ``diffuse.albedo``, ``alpha``) is itself;
    * a bare name the model does not have as such (``f0``, ``alpha``, ``ks`` on ``lambert+2ggx``) names that
      parameter of every term having it (``f0=1`` holds lobe1.f0 and lobe2.f0: a tied f0 applies to all lobes);
    * a per-channel name (``lobe1.ks.r``, ``kd.g``, ``f0.b``, as in the labels of the uncertainties and the
      redundancy notes) holds one channel; the three channels of a parameter must then all be given (a fit
      holds a colour parameter whole), and they combine into one RGB value.

    Anything else is a one-line :class:`ConfigError` listing the valid names."""
    params = cls.PARAMS
    out: dict = {}
    channels: dict[str, dict[int, Any]] = {}

    def valid() -> str:
        rgb = [k for k, v in params.items() if v.kind == "rgb"]
        extra = f" (per channel: {rgb[0]}.r, {rgb[0]}.g, {rgb[0]}.b, ...)" if rgb else ""
        return f"{cls.name} has {', '.join(params)}{extra}"

    for name, value in fixed.items():
        name = str(name).strip()
        base, _, ch = name.rpartition(".")
        if name not in params and ch in CHANNELS and base:
            targets = [base] if base in params else [p for p in params if p.rsplit(".", 1)[-1] == base]
            targets = [t for t in targets if params[t].kind == "rgb"]
            if not targets:
                raise ConfigError.field(source, f"{cls.name}.{name}", value, f"unknown parameter; {valid()}")
            if np.ndim(value) != 0:
                raise ConfigError.field(source, f"{cls.name}.{name}", value, "one channel takes one number")
            for t in targets:
                channels.setdefault(t, {})[CHANNELS.index(ch)] = value
            continue
        targets = [name] if name in params else [p for p in params if p.rsplit(".", 1)[-1] == name]
        if not targets:
            raise ConfigError.field(source, f"{cls.name}.{name}", value, f"unknown parameter; {valid()}")
        out.update({t: value for t in targets})
    for t, per in channels.items():
        if t in out:
            raise ConfigError.field(source, f"{cls.name}.{t}", out[t], "given both whole and per channel")
        if len(per) != 3:
            missing = ", ".join(f"{t}.{c}" for j, c in enumerate(CHANNELS) if j not in per)
            raise ConfigError.field(source, f"{cls.name}.{t}.{CHANNELS[min(per)]}", per[min(per)],
                                    f"a colour parameter is held whole: also give {missing} (or {t}=R,G,B)")
        out[t] = [per[j] for j in range(3)]
    return out


#: Colour parameters fitted *tied* by default: one value shared by R, G and B, searched as a shape
#: parameter. The Fresnel reflectance f0 multiplies the specular weight (ks·F(f0), Schlick 1994), so per
#: channel it would duplicate ks; the colour lives in ks, while a shared f0 sets how the specular
#: reflectance rises towards grazing θd — what tells a dielectric (f0 ≈ 0.04) from a metal (f0 ≈ 1).
AUTO_TIED = ("f0",)


def _base(key: str) -> str:
    return key.split(".")[-1]


def auto_tied(cls: type[BRDF], fixed: dict, free=()) -> tuple[str, ...]:
    """The :data:`AUTO_TIED` parameters of ``cls`` (``f0``, ``lobe1.f0``, ...) that are neither fixed nor
    freed per channel (``free`` lists parameters fitted per channel: ``f0`` or ``lobe1.f0``)."""
    free = set(free)
    return tuple(k for k, spec in cls.PARAMS.items()
                 if _base(k) in AUTO_TIED and spec.kind == "rgb" and k not in fixed
                 and k not in free and _base(k) not in free)


def log_floor(hi: float, tied: bool = False) -> float:
    """Lower end of the log-scaled search of a parameter whose range starts at 0: 10⁻⁶ of its upper end
    (10⁻³ for a tied reflectance f0, see :meth:`Layout.search_space`). A range that starts above 0 is
    searched from its own lower end."""
    return hi * (1e-3 if tied else 1e-6)


class _SearchMap:
    """Maps between shape parameters and the search space (log-scaled where ``is_log``), for classes
    with ``search_space()``, ``shape_lo`` and ``shape_hi``."""

    def to_shape(self, u: np.ndarray) -> np.ndarray:
        """Shape parameters of a point of the search space (clipped to the model bounds)."""
        _, _, is_log = self.search_space()
        u = np.asarray(u, dtype=np.float64)
        s = u.copy()
        s[is_log] = np.exp(u[is_log])
        return np.clip(s, self.shape_lo, self.shape_hi)

    def to_u(self, s: np.ndarray) -> np.ndarray:
        u_lo, u_hi, is_log = self.search_space()
        with np.errstate(divide="ignore"):
            u = np.where(is_log, np.log(np.maximum(s, 1e-300)), s)
        return np.clip(u, u_lo, u_hi)


class Layout(_SearchMap):
    """Free parameters of a model class, packed into one vector ``p = [colours (K×3, per channel), shapes (S)]``.

    Parameters
    ----------
    model : str or BRDF subclass
        Registry name (:data:`gonio.brdf.MODELS`) or class.
    fixed : dict
        Parameters held at a value (choices default to their default).
    tied : sequence of str
        ``rgb`` parameters fitted as one value shared by R, G, B (a shape parameter; see
        :data:`AUTO_TIED`).
    """

    def __init__(self, model: str | type[BRDF], fixed: dict[str, Any] | None = None, tied=(), linked=()):
        if isinstance(model, str):
            model = model_class(model)
        self.cls = model
        self.name = model.name
        fixed = dict(fixed or {})
        unknown = sorted(set(fixed) - set(model.PARAMS))
        if unknown:
            raise ConfigError.field("--fix", f"{model.name}.{unknown[0]}", fixed[unknown[0]], "unknown parameter")
        self.tied = tuple(t for t in tied if t not in fixed)
        bad = sorted(set(self.tied) - {k for k, v in model.PARAMS.items() if v.kind == "rgb"})
        if bad:
            raise ConfigError.field("--fix", f"{model.name}.{bad[0]}", "tied", "only RGB parameters can be tied")
        self.fixed: dict[str, Any] = {}
        self.colour: list[str] = []
        self.shape: list[str] = []
        for name, spec in model.PARAMS.items():
            if name in fixed:
                self.fixed[name] = spec.coerce(model.name, name, fixed[name], "--fix")
            elif spec.kind == "choice":
                if spec.default is None:
                    raise ConfigError(f"{model.name}.{name}: a choice parameter must be fixed ({', '.join(spec.choices)})")
                self.fixed[name] = spec.default
            elif spec.kind == "rgb" and name not in self.tied and name not in dict(linked):
                self.colour.append(name)
            elif name not in dict(linked):
                self.shape.append(name)
        #: (dst, src, ratio name): colour ``dst`` = ratio × colour ``src`` (one chromaticity; see :func:`linked_lobes`)
        self.links = [(dst, src, f"{dst}/{src}") for dst, src in linked if dst not in fixed and src in self.colour]
        self.extra = {r: Param("scalar", 0.0, RATIO_MAX, 1.0, doc=f"{dst} / {src}, one value for R, G, B")
                      for dst, src, r in self.links}
        self.shape += list(self.extra)
        self.K, self.S = len(self.colour), len(self.shape)
        self.n_params = 3 * self.K + self.S
        b = {**model.bounds(), **{r: (0.0, RATIO_MAX) for r in self.extra}}
        self.colour_lo = np.array([b[k][0] for k in self.colour], dtype=np.float64)
        self.colour_hi = np.array([b[k][1] for k in self.colour], dtype=np.float64)
        self.shape_lo = np.array([b[k][0] for k in self.shape], dtype=np.float64)
        self.shape_hi = np.array([b[k][1] for k in self.shape], dtype=np.float64)

    # -- packing ----------------------------------------------------------------------------
    def labels(self) -> list[str]:
        """Names of the entries of ``p``: ``kd.r, kd.g, kd.b, ..., alpha``."""
        return [f"{k}.{c}" for k in self.colour for c in CHANNELS] + list(self.shape)

    def pack(self, colour: np.ndarray, shape: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(colour, dtype=np.float64).reshape(-1), np.asarray(shape, dtype=np.float64)])

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(colour (K, 3), shape (S,))`` of a packed vector."""
        p = np.asarray(p, dtype=np.float64)
        return p[: 3 * self.K].reshape(self.K, 3), p[3 * self.K:]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of ``p`` from the model's ``PARAMS``."""
        lo = np.concatenate([np.repeat(self.colour_lo, 3), self.shape_lo])
        hi = np.concatenate([np.repeat(self.colour_hi, 3), self.shape_hi])
        return lo, hi

    def params(self, colour: np.ndarray, shape: np.ndarray) -> dict[str, Any]:
        """Model constructor arguments (fixed ones included)."""
        out: dict[str, Any] = dict(self.fixed)
        for k, name in enumerate(self.colour):
            out[name] = np.asarray(colour[k], dtype=np.float64)
        for j, name in enumerate(self.shape):
            if name not in self.extra:
                out[name] = float(shape[j])
        for dst, src, r in self.links:
            out[dst] = float(shape[self.shape.index(r)]) * np.asarray(colour[self.colour.index(src)], dtype=np.float64)
        return out

    def spec(self, name: str) -> Param:
        """The :class:`~gonio.brdf.base.Param` of a free parameter (a link's ratio included)."""
        return self.extra.get(name) or self.cls.PARAMS[name]

    def linked_colour_hi(self, shape) -> np.ndarray:
        """Upper bounds (K,) of the colours at ``shape``: the model's, and for the source of a link
        (:func:`linked_lobes`) the linked colour's upper bound over the ratio, so that ``lobe2.ks`` = w ·
        ``lobe1.ks`` stays within its range whatever the solver."""
        hi = np.array(self.colour_hi, dtype=np.float64)
        if self.links:
            steps = self.__dict__.get("_link_steps")
            if steps is None:  # (colour index of the source, shape index of the ratio, the linked colour's upper bound)
                bounds = self.cls.bounds()
                steps = self._link_steps = [(self.colour.index(src), self.shape.index(r), float(bounds[dst][1]))
                                            for dst, src, r in self.links]
            shape = np.asarray(shape, dtype=np.float64)
            for k, j, top in steps:
                w = max(float(shape[j]), 1e-300)
                hi[k] = min(hi[k], top / w)
        return hi

    def link_values(self, shape) -> dict[str, float]:
        """The fitted ratios of the links (``{"lobe2.ks/lobe1.ks": w}``)."""
        return {r: float(shape[self.shape.index(r)]) for _, _, r in self.links}

    def build(self, colour: np.ndarray, shape: np.ndarray) -> BRDF:
        """The model instance (raises :class:`ConfigError` if the model rejects the combination)."""
        return self.cls(**self.params(colour, shape))

    def eval(self, colour, shape, wi, wo) -> np.ndarray:
        return self.build(colour, shape).eval(wi, wo)

    # -- search space of the shape parameters -------------------------------------------------
    def search_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u_lo, u_hi, is_log)``: bounded search box of the shape parameters.

        Wide positive ranges (hi/lo > 100) are searched in log space (roughness, exponents); an
        infinite upper bound is capped at 10⁴ × max(default, 1). A range starting at 0 is searched from
        :func:`log_floor` (10⁻⁶ of its upper end; tied reflectances f0 from 10⁻³, below any real material:
        f0 ≥ 0.02 for refractive index ≥ 1.33); a range starting above 0 from its lower end.
        """
        cached = self.__dict__.get("_space")
        if cached is not None:
            return cached
        u_lo, u_hi, is_log = [], [], []
        for j, name in enumerate(self.shape):
            spec = self.spec(name)
            lo, hi = float(self.shape_lo[j]), float(self.shape_hi[j])
            if not np.isfinite(hi):
                hi = 1e4 * max(abs(float(spec.default or 1.0)), 1.0)
            if not np.isfinite(lo):
                lo = -hi
            log = lo >= 0 and hi > 0 and hi / max(lo, 1e-300) >= 100
            if log:
                if lo <= 0:
                    lo = RATIO_MIN if name in self.extra else log_floor(hi, name in self.tied)
                u_lo.append(np.log(lo)), u_hi.append(np.log(hi))
            else:
                u_lo.append(lo), u_hi.append(hi)
            is_log.append(log)
        self._space = (np.array(u_lo), np.array(u_hi), np.array(is_log, dtype=bool))
        return self._space

    def default_shape(self) -> np.ndarray:
        out = []
        for j, name in enumerate(self.shape):
            d = self.spec(name).default
            out.append(float(d) if d is not None else 0.5 * (self.shape_lo[j] + min(self.shape_hi[j], 1.0)))
        return np.clip(np.array(out, dtype=np.float64), self.shape_lo, self.shape_hi)


class SubSpace(_SearchMap):
    """The search space of some of a layout's shape parameters (the others are profiled out, see
    :class:`gonio.fit.solve.ProfiledProjection`); the same search API as :class:`Layout`."""

    def __init__(self, layout: Layout, keep):
        self.layout = layout
        self.keep = np.asarray(keep, dtype=int)
        self.S = int(self.keep.size)
        self.shape_lo, self.shape_hi = layout.shape_lo[self.keep], layout.shape_hi[self.keep]

    def search_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u_lo, u_hi, is_log = self.layout.search_space()
        return u_lo[self.keep], u_hi[self.keep], is_log[self.keep]

    def default_shape(self) -> np.ndarray:
        return self.layout.default_shape()[self.keep]


class Basis:
    """Evaluates f = f₀(s) + Σₖ aₖ Bₖ(s) for the colour parameters aₖ of a :class:`Layout`.

    The basis comes from the model itself: f₀ with every colour at its reference value (0 when allowed),
    Bₖ from a unit step of colour k. :attr:`separable` is False when the model is not affine in its
    colours (checked on a probe of the data at random colours); fits then use plain least squares.
    Basis functions that do not depend on the shape parameters (a Lambert term) are computed once.

    A *kernel* ``kernel(data, fixed, shape) -> (offset (N,3) or None, [B_k (N,) or (N,3)])`` may replace
    the model evaluation: it computes the same functions from the geometry cached on the data
    (:class:`gonio.fit.data.FitData`), which is what makes large fits fast (see :mod:`gonio.fit.kernels`).
    """

    def __init__(self, layout: Layout, data, kernel: Callable | None = None, seed: int = 0):
        self.layout = layout
        self.data = data
        self.kernel = kernel
        self.ref = np.where((layout.colour_lo <= 0) & (layout.colour_hi >= 0), 0.0, layout.colour_lo)
        self.step = np.where(self.ref + 1.0 <= layout.colour_hi, 1.0, layout.colour_hi - self.ref)
        self._static: dict[int, np.ndarray] = {}
        self._offset_static: np.ndarray | None = None
        self._last: tuple | None = None
        self.separable = layout.K > 0 and self._check(np.random.default_rng(seed))

    def _model_basis(self, shape, wi, wo):
        L = self.layout
        base = np.repeat(self.ref[:, None], 3, axis=1)
        f0 = L.eval(base, shape, wi, wo)
        cols = []
        for k in range(L.K):
            c = base.copy()
            c[k] += self.step[k]
            cols.append((L.eval(c, shape, wi, wo) - f0) / self.step[k])
        return f0, cols

    def _check(self, rng) -> bool:
        """Affine in the colours, and which basis functions are shape-independent."""
        L, d = self.layout, self.data
        idx = rng.choice(len(d), size=min(len(d), 256), replace=False)
        wi, wo = d.wi[idx], d.wo[idx]
        u_lo, u_hi, _ = L.search_space()
        shapes = [L.to_shape(rng.uniform(u_lo, u_hi)) for _ in range(2)]
        try:
            bases = [self._model_basis(s, wi, wo) for s in shapes]
            for s, (f0, cols) in zip(shapes, bases):
                a = self.ref[:, None] + rng.uniform(0.05, 0.3, (L.K, 3)) * self.step[:, None]
                want = L.eval(a, s, wi, wo)
                got = f0 + sum((a[k] - self.ref[k]) * cols[k] for k in range(L.K))
                scale = max(np.abs(want).max(), 1e-300)
                if not np.allclose(got, want, rtol=1e-7, atol=1e-9 * scale):
                    return False
        except GonioError:
            return False
        if self.kernel is None:
            (f0a, ca), (f0b, cb) = bases
            for k in range(L.K):
                if L.S == 0 or np.array_equal(ca[k], cb[k]):
                    self._static[k] = np.empty(0)  # placeholder; filled on first full evaluation
            if L.S == 0 or np.array_equal(f0a, f0b):
                self._offset_static = np.empty(0)
        return True

    @property
    def colour_hi_reason(self) -> str:
        return getattr(self.kernel, "colour_hi_reason", "a bound set by the shape parameters")

    def colour_hi(self, shape) -> np.ndarray | None:
        """Shape-dependent upper bounds of the colours (the kernel's ``colour_hi``, e.g. a lobe's albedo ≤ 1), or
        None."""
        hook = getattr(self.kernel, "colour_hi", None)
        if hook is None:
            return None
        return hook(self.layout, dict(zip(self.layout.shape, map(float, np.asarray(shape)))))

    def __call__(self, shape: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """``(f₀ (N, 3), [B_k (N, 3) or (N,)])`` at shape parameters ``shape`` on the full data."""
        key = tuple(np.asarray(shape, dtype=np.float64).tolist())
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        out = self._compute(np.asarray(shape, dtype=np.float64))
        self._last = (key, out)
        return out

    def _zeros(self):
        if getattr(self, "_zero", None) is None:
            self._zero = _zero_offset(self.data.y.shape)
        return self._zero

    def _compute(self, shape):
        L, d = self.layout, self.data
        if self.kernel is not None:
            f0, cols = self.kernel(d, L, dict(zip(L.shape, map(float, shape))))
            return (self._zeros() if f0 is None else f0), cols
        need_model = (self._offset_static is None or self._offset_static.size == 0
                      or any(k not in self._static or self._static[k].size == 0 for k in range(L.K)))
        if need_model:
            f0, cols = self._model_basis(shape, d.wi, d.wo)
            if self._offset_static is not None:
                self._offset_static = f0
            for k in list(self._static):
                self._static[k] = cols[k]
            return f0, cols
        return self._offset_static, [self._static[k] for k in range(L.K)]


class ZeroOffset(np.ndarray):
    """A read-only array of zeros that says so (``is_zero``): consumers skip arithmetic with it."""

    is_zero = True


def _zero_offset(shape) -> np.ndarray:
    z = np.zeros(shape).view(ZeroOffset)
    z.setflags(write=False)
    return z


class SumBasis:
    """The :class:`Basis` of a sum of lobes (:mod:`gonio.brdf.lobes`), assembled from one basis per
    term: f₀ = Σ f₀,term and the colour bases of each term. A term's basis is recomputed only when its
    own shape parameters change, and each term may use a kernel (:mod:`gonio.fit.kernels`)."""

    def __init__(self, layout: Layout, data, use_kernels: bool = True, seed: int = 0):
        from gonio.fit.kernels import kernel_for

        self.layout, self.data = layout, data
        self.parts = []
        for slot, cls, fixed in layout.cls.PARTS:
            own_fixed = dict(fixed)
            own_fixed.update({k.split(".", 1)[1]: v for k, v in layout.fixed.items() if k.split(".", 1)[0] == slot})
            own_tied = [k.split(".", 1)[1] for k in layout.tied if k.split(".", 1)[0] == slot]
            sub = Layout(cls, own_fixed, own_tied)
            kern = kernel_for(sub) if use_kernels else None
            b = Basis(sub, data, kern, seed) if sub.K else None
            shape_idx = [layout.shape.index(f"{slot}.{n}") for n in sub.shape]
            colour_names = [f"{slot}.{n}" for n in sub.colour]
            self.parts.append((sub, b, shape_idx, colour_names))
        self.ref = np.where((layout.colour_lo <= 0) & (layout.colour_hi >= 0), 0.0, layout.colour_lo)
        self.separable = layout.K > 0 and all(b is not None and b.separable for _, b, _, _ in self.parts)
        self._link_index = [layout.shape.index(r) for _, _, r in layout.links]

    #: What the shape-dependent colour bound of :meth:`colour_hi` is (for ``at_bound``).
    colour_hi_reason = "a linked colour (ratio x its source) at its upper bound"

    def colour_hi(self, shape) -> np.ndarray | None:
        """Upper bounds of the colours at ``shape`` when colours are linked (:meth:`Layout.linked_colour_hi`);
        None without links."""
        return self.layout.linked_colour_hi(shape) if self.layout.links else None

    def __call__(self, shape):
        shape = np.asarray(shape, dtype=np.float64)
        f0 = None
        cols: dict[str, np.ndarray] = {}
        for sub, b, shape_idx, names in self.parts:
            pf0, pcols = b(shape[shape_idx])
            if not getattr(pf0, "is_zero", False):
                f0 = pf0 if f0 is None else f0 + pf0
            cols.update(zip(names, pcols))
        for (dst, src, r), j in zip(self.layout.links, self._link_index):  # colour dst = w · colour src: src → B_src + w B_dst
            w = shape[j]
            a, b = cols[src], cols.pop(dst)
            if a.ndim != b.ndim:
                a, b = np.broadcast_to(a if a.ndim == 2 else a[:, None], self.data.y.shape), (b if b.ndim == 2 else b[:, None])
            cols[src] = a + w * b
        if f0 is None:
            if getattr(self, "_zero", None) is None:
                self._zero = _zero_offset(self.data.y.shape)
            f0 = self._zero
        return f0, [cols[n] for n in self.layout.colour]


def make_basis(layout: Layout, data, use_kernels: bool = True, seed: int = 0):
    """The colour basis of ``layout`` on ``data`` (:class:`SumBasis` for sums, else :class:`Basis`,
    with a kernel of :mod:`gonio.fit.kernels` where one applies)."""
    from gonio.fit.kernels import kernel_for

    if layout.K == 0:
        return None
    if getattr(layout.cls, "PARTS", None):
        return SumBasis(layout, data, use_kernels, seed)
    return Basis(layout, data, kernel_for(layout) if use_kernels else None, seed)


#: Range of the ratio of a linked colour to its source (:func:`linked_lobes`), searched in log space.
RATIO_MIN, RATIO_MAX = 1e-6, 1e3


def linked_lobes(cls) -> tuple[tuple[str, str], ...]:
    """Colour links of a sum that repeats a specular lobe (``lambert+2ggx``): every later copy's ``ks`` is a
    ratio (one value for R, G, B) times the first copy's, so the lobes share one chromaticity — a narrow and a
    broad lobe of one coating, never one red and one blue lobe of equal width standing in for a lobe whose
    width varies by channel (issue 29). ``gonio.fit.fit`` fits with these links unless ``free`` names the
    later lobes' ``ks``."""
    parts = getattr(cls, "PARTS", ())
    groups: dict[tuple, list[str]] = {}
    for slot, part, fixed in parts:
        if "ks" in part.PARAMS and part.PARAMS["ks"].kind == "rgb":
            groups.setdefault((part, tuple(sorted(dict(fixed).items()))), []).append(slot)
    return tuple((f"{s}.ks", f"{slots[0]}.ks") for slots in groups.values() for s in slots[1:])


#: Smallest ratio of widths between the broad and the narrow one of two repeated lobes (a sum such as
#: ``lambert+2ggx``): lobes closer than that would be told apart by colour only.
LOBE_RATIO_MIN = 2.0
_WIDTHS = ("alpha", "roughness")


class SeparatedLobes(_SearchMap):
    """The search space of a layout whose sum repeats a lobe, with the lobes separated by *shape*: the
    width (α, roughness) of each repeated lobe after the first is searched as its ratio to the previous
    one's, at least :data:`LOBE_RATIO_MIN` (log-scaled). Without it a two-lobe fit of a coloured material
    may split the lobes by channel — one red, one blue, equal widths — instead of a narrow and a broad
    lobe (issue 14). Same search API as :class:`Layout`; :func:`separated` builds it when it applies."""

    def __init__(self, layout: Layout, chains: list[list[int]]):
        self.layout = layout
        self.chains = chains
        self.S = layout.S
        self.shape_lo, self.shape_hi = layout.shape_lo, layout.shape_hi

    def search_space(self):
        u_lo, u_hi, is_log = (a.copy() for a in self.layout.search_space())
        for chain in self.chains:
            for prev, j in zip(chain, chain[1:]):
                u_lo[j] = np.log(LOBE_RATIO_MIN)
                u_hi[j] = max(np.log(self.shape_hi[j] / max(self.shape_lo[prev], 1e-300)), u_lo[j] + 1e-6)
                is_log[j] = True
        return u_lo, u_hi, is_log

    def to_shape(self, u):
        u = np.asarray(u, dtype=np.float64)
        base = u.copy()
        steps = self.__dict__.get("_steps")
        if steps is None:  # per ratio: (previous, this, placeholder of this in u, its lower and upper bound)
            _, _, is_log = self.layout.search_space()
            steps = self._steps = [(prev, j, np.log(self.shape_lo[j]) if is_log[j] else self.shape_lo[j],
                                    self.shape_lo[j], self.shape_hi[j])
                                   for chain in self.chains for prev, j in zip(chain, chain[1:])]
        for _, j, placeholder, _, _ in steps:
            base[j] = placeholder
        s = self.layout.to_shape(base)
        for prev, j, _, lo, hi in steps:  # in chain order: a later lobe's width from the one before, already set
            s[j] = min(max(s[prev] * np.exp(u[j]), lo), hi)  # np.clip's value, for a scalar
        return s

    def to_u(self, s):
        s = np.asarray(s, dtype=np.float64)
        u = self.layout.to_u(s)
        lo, hi, _ = self.search_space()
        for chain in self.chains:
            for prev, j in zip(chain, chain[1:]):
                u[j] = np.clip(np.log(max(s[j] / max(s[prev], 1e-300), 1e-300)), lo[j], hi[j])
        return u

    def default_shape(self):
        s = self.layout.default_shape()
        for chain in self.chains:
            for prev, j in zip(chain, chain[1:]):
                s[j] = min(max(s[j], 4.0 * s[prev]), self.shape_hi[j])
        return s


def separated(layout: Layout) -> SeparatedLobes | None:
    """:class:`SeparatedLobes` for a sum that repeats a lobe with a free width parameter, else None."""
    parts = getattr(layout.cls, "PARTS", ())
    groups: dict[tuple, list[int]] = {}
    for slot, cls, fixed in parts:
        for w in _WIDTHS:
            name = f"{slot}.{w}"
            if name in layout.shape:
                groups.setdefault((cls, tuple(sorted(dict(fixed).items())), w), []).append(layout.shape.index(name))
    chains = [idx for idx in groups.values() if len(idx) > 1]
    return SeparatedLobes(layout, chains) if chains else None
