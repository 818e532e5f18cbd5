"""What renderer exports share: a fitted model as a diffuse term plus microfacet lobes, the error of a
renderer's material against the model, and the rule "exact, or approximate only when asked".

A renderer material is written *exactly* when its published formulas reproduce the model (relative
error below :data:`EXACT`); otherwise it is the closest material of the target under a fixed mapping,
and it is written only with ``approx=True`` (``--approx``), its error printed; without it the export is
refused in one line with the reason and the error it would have.

The error is the cosine-weighted relative RMS difference over direction pairs ``wi``, ``wo`` drawn
cosine-distributed over the upper hemisphere (fixed seed, :data:`N_PAIRS` pairs)::

    e = sqrt(Σ (f_target − f_model)²) / sqrt(Σ f_model²)       (all three channels)

— the error of the reflected radiance under uniform lighting, as a renderer would show it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gonio.errors import ConfigError

__all__ = ["Lobe", "Decomposed", "decompose", "direction_pairs", "relative_error", "Exported", "closest_lobes",
           "EXACT", "TOLERANCE", "N_PAIRS", "single_dielectric"]

#: Relative error below which an export counts as exact (float64 round-off of the formulas).
EXACT = 1e-9
#: Relative error below which an export is written without --approx (a fitted f0 of 0.9999977 exported
#: as 1): far below any measurement's noise; its error is printed.
TOLERANCE = 1e-4
N_PAIRS = 8192


@dataclass(frozen=True)
class Lobe:
    """One microfacet lobe: ``ks · D G F_schlick(f0) / (4 cosθi cosθo)`` (gonio.brdf.microfacet)."""

    ks: np.ndarray
    alpha: float
    f0: np.ndarray
    distribution: str


@dataclass(frozen=True)
class Decomposed:
    """A model as ``diffuse/π + Σ lobes``."""

    diffuse: np.ndarray
    lobes: tuple[Lobe, ...]


def _rgb(v) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()


def decompose(model, target: str, approx: bool = False, reasons: list | None = None) -> Decomposed:
    """``model`` as a diffuse term plus microfacet lobes; :class:`ConfigError` naming ``target`` for a
    model that is not such a sum (Phong, Ward, ABC, ...), unless ``approx``: then the sum is
    :func:`closest_lobes` (fitted to the model) and ``reasons`` receives why."""
    if approx:
        try:
            return decompose(model, target)
        except ConfigError:
            stand_in, why = closest_lobes(model, target)
            if reasons is not None:
                reasons.append(why)
            return decompose(stand_in, target)
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.lobes import Sum
    from gonio.brdf.microfacet import Microfacet

    diffuse, lobes = np.zeros(3), []
    stack = [model]
    while stack:
        m = stack.pop(0)
        if isinstance(m, Sum):
            stack = list(m.parts) + stack
        elif isinstance(m, Lambert):
            diffuse = diffuse + _rgb(m.albedo)
        elif isinstance(m, Microfacet):
            diffuse = diffuse + _rgb(m.kd)
            if np.any(_rgb(m.ks) > 0):
                lobes.append(Lobe(_rgb(m.ks), float(m.alpha), _rgb(m.f0), str(m.distribution)))
        else:
            raise ConfigError.field(target, "model", m.name,
                                    "has no counterpart to export: exportable are lambert, microfacet/ggx/beckmann "
                                    "lobes and their sums; pass --approx for the closest (a lambert+ggx fitted to "
                                    "it, its error printed)")
    return Decomposed(diffuse, tuple(lobes))


def single_dielectric(model, target: str, f0_max: float) -> Decomposed | None:
    """``model`` decomposed (:func:`decompose`) when it is a diffuse term under exactly one lobe with a grey
    f0 in (0, ``f0_max``) — a dielectric coating: plastics, paints' clear coats, which renderers have a layered
    material for — else None."""
    try:
        dec = decompose(model, target)
    except ConfigError:
        return None
    if len(dec.lobes) != 1:
        return None
    f0 = dec.lobes[0].f0
    return dec if np.ptp(f0) <= 1e-9 and 0.0 < f0[0] < f0_max else None


def direction_pairs(n: int = N_PAIRS, seed: int = 12345) -> tuple[np.ndarray, np.ndarray]:
    """Cosine-distributed ``wi``, ``wo`` (n, 3) over the upper hemisphere (Malley's method)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        u1, u2 = rng.random(n), rng.random(n)
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        out.append(np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - u1, 1e-12))], axis=-1))
    return out[0], out[1]


def _fit_pairs(n: int = N_PAIRS, seed: int = 54321) -> tuple[np.ndarray, np.ndarray]:
    """Direction pairs to fit a stand-in lobe on: :func:`direction_pairs` plus as many pairs whose ``wo`` is
    the mirror direction of ``wi`` tilted by log-uniform angles from 10⁻⁴ to 1 rad, so that razor-thin
    peaks (polished metals, α ~ 10⁻³) are sampled."""
    from gonio.geometry import frame_from_normal, from_spherical, to_world

    wi, wo = direction_pairs(n, seed)
    rng = np.random.default_rng(seed + 1)
    tilt = np.exp(rng.uniform(np.log(1e-4), 0.0, n))
    mirror = wi * np.array([-1.0, -1.0, 1.0])
    wo2 = to_world(from_spherical(tilt, rng.uniform(0, 2 * np.pi, n)), frame_from_normal(mirror))
    keep = wo2[:, 2] > 0.05
    return np.concatenate([wi, wi[keep]]), np.concatenate([wo, wo2[keep]])


def closest_lobes(model, target: str):
    """A ``lambert+ggx`` sum fitted to ``model`` (values at :func:`_fit_pairs`, gonio's default robust loss,
    :func:`gonio.fit.fit.fit`), for a model no renderer plugin has (ABC, GTR, Phong, ...): the closest
    material a renderer can then take, the reason as a string. The export's error is still measured against
    ``model`` itself."""
    from gonio.fit.fit import fit

    if callable(getattr(model, "stand_in", None)):  # the model knows its closest analytic form (gonio.brdf.dupuy)
        stand_in, why = model.stand_in()
        return stand_in, why.replace("no counterpart", f"no {target} counterpart")
    wi, wo = _fit_pairs(4096)
    r = fit((wi, wo, model.eval(wi, wo)), "lambert+ggx", max_theta_deg=None, report=False, n_starts=1)
    return r.model, (f"{model.name} has no {target} counterpart: exported as the lambert+ggx fitted to it "
                     f"(lobe alpha {r.params['lobe1.alpha']:.3g})")


def relative_error(f_target: np.ndarray, f_model: np.ndarray) -> float:
    """The module docstring's e."""
    num = float(np.sqrt(np.sum((f_target - f_model) ** 2)))
    den = float(np.sqrt(np.sum(f_model ** 2)))
    return num / den if den > 0 else (0.0 if num == 0 else float("inf"))


@dataclass
class Exported:
    """A renderer material: its text, its relative error against the model, why it is not exact."""

    target: str
    text: str
    error: float
    reasons: list[str] = field(default_factory=list)

    @property
    def exact(self) -> bool:
        return self.error < EXACT

    def check(self, approx: bool, option: str) -> "Exported":
        """Self if exact or ``approx``; else the one-line refusal (reasons and error named)."""
        if self.error < TOLERANCE or approx:
            return self
        why = "; ".join(dict.fromkeys(self.reasons)) or "its formulas differ from the model's"
        raise ConfigError(f"{option}: {self.target} cannot represent the model exactly (relative error "
                          f"{self.error:.3g}: {why}); pass --approx to write the closest {self.target} material anyway")

    def write(self, path, option: str) -> "Exported":
        """Write :attr:`text` to ``path``; a failure is one line naming ``option``."""
        from gonio.io.outputs import write_text_atomically

        try:
            write_text_atomically(path, self.text)
        except OSError as exc:
            raise ConfigError.field(option, option.lstrip("-"), str(path), f"cannot write ({exc.strerror or exc})") from None
        return self

    def describe(self) -> str:
        if self.exact:
            return f"{self.target}: exact (relative error {self.error:.1e})"
        if self.error < TOLERANCE:
            return (f"{self.target}: within tolerance, relative error {self.error:.1e} "
                    f"({'; '.join(dict.fromkeys(self.reasons))})")
        return (f"{self.target}: APPROXIMATION, cosine-weighted relative RMS error {100 * self.error:.2f} % "
                f"({'; '.join(dict.fromkeys(self.reasons))})")
