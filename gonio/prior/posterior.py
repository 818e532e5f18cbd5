"""Bayesian reconstruction of a whole BRDF from a few samples under a :class:`~gonio.prior.model.Prior`.

Per colour channel, the prior's linear-Gaussian model (:mod:`gonio.prior.model`) observed at sample j:

    y_j = ln((f_j + ε)/(f_ref(ω_j) + ε)) = h_j·(μ + B·a) + e_j,
    e_j ~ N(0, v_j),  v_j = σ_u,j² + c_j·h_j·τ²,

``h_j`` the trilinear weights of the sample's direction pair (:meth:`gonio.prior.grid.PriorGrid.weights`),
``σ_u,j = σ_j / (f_j + ε)`` the sample's own standard uncertainty in the mapped domain (delta method,
:mod:`gonio.prior.mapping`), ``h_j·τ²`` the prior's residual variance there (what the components cannot say).
The residual is a property of the material at that direction, shared by samples that fall together: ``c_j``
is the number of samples whose nearest node is the same as sample j's, so a pose's cluster of samples (one per
target tile, slightly different wi/wo) carries the residual's uncertainty once, not c_j times less.

The posterior is Gaussian (Bishop, *Pattern Recognition and Machine Learning*, 2006, Eqs. 3.50–3.51), kept in
information form so samples can be added one pose at a time (:meth:`Posterior.update`):

    P = diag(1/s²) + Aᵀ V⁻¹ A,   b = Aᵀ V⁻¹ (y − Hμ),   S = P⁻¹,   m = S b,    (A = H B)

Reconstruction: u = μ + B m at the nodes, per-node variance diag(B S Bᵀ) + τ²; at any direction pair the nodes
are interpolated trilinearly (the standard deviation too: an upper bound of the interpolated value's, by the
Cauchy–Schwarz inequality) and mapped back, f = ((f_ref w + ε)e^u − ε)/w (the posterior *median* of f, a
monotone map of the Gaussian u) with σ_f = (f + ε)·σ_u (delta method); 0 and σ = 0 below the horizon.

Consistency with the prior (":meth:`Posterior.quality`"): under the model, the whitened prior-predictive
residual χ² = (y − Hμ)ᵀ (A diag(s²) Aᵀ + V)⁻¹ (y − Hμ) follows a χ² distribution with 3n degrees of freedom
(n samples × 3 channels); it is computed in the numerically stable form (Woodbury's identity)
χ² = Σ (y − Hμ − A m)²/v + mᵀ diag(1/s²) m.
A p-value below :data:`OUT_OF_SPAN_P` says the material is outside what the prior describes.

Expected error (:meth:`Posterior.expected_error`): the posterior RMS error of u over the valid MERL cells,
√((tr(BᵀQB·S) + Σ Q τ²)/Σ Q) with Q the nodes' shares of the cells — u differs from ln(f + ε) by a constant, so
this is about the relative RMS error of f where f ≫ ε; the cube-root error of :mod:`gonio.fit.metrics` is
about a third of a relative error (benchmarks sparse measures the ratio).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.errors import DataError
from gonio.prior.mapping import cos_weight, from_mapped, sigma_from_mapped, sigma_to_mapped, to_mapped
from gonio.prior.model import Prior

__all__ = ["Posterior", "Quality", "observation_rows", "OUT_OF_SPAN_P"]

#: p-value of the consistency χ² below which a material is said to be outside the prior's span.
OUT_OF_SPAN_P = 1e-3


def _check_samples(wi, wo, f, sigma, source: str = "samples"):
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(f, dtype=np.float64).reshape(-1, 3)
    sigma = np.asarray(sigma, dtype=np.float64).reshape(-1, 3)
    if not (len(wi) == len(wo) == len(f) == len(sigma)):
        raise DataError(f"{source}: wi, wo, f, sigma have {len(wi)}, {len(wo)}, {len(f)}, {len(sigma)} rows")
    for name, a in (("wi", wi), ("wo", wo), ("f", f)):
        bad = ~np.isfinite(a).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(f"{source}: sample {i}: {name} = {a[i].tolist()} is not finite")
    bad = ~(np.isfinite(sigma) & (sigma > 0)).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"{source}: sample {i}: sigma = {sigma[i].tolist()}: a reconstruction weighs each sample by "
                        "its standard uncertainty, which must be finite and > 0")
    return wi, wo, f, sigma


def observation_rows(prior: Prior, wi, wo):
    """``(H, A, f_ref)`` of direction pairs: sparse trilinear weights (n, G), design rows A = H·B (n, K) and the
    interpolated reference BRDF (n,)."""
    h = prior.grid.weights(wi, wo)
    return h, np.asarray(h @ prior.basis), h @ prior.f_ref


@dataclass(frozen=True)
class Quality:
    """How the samples agree with the prior (one line: :meth:`line`)."""

    n_samples: int
    chi2: float
    dof: int
    p_value: float

    @property
    def out_of_span(self) -> bool:
        return self.dof > 0 and self.p_value < OUT_OF_SPAN_P

    def line(self) -> str:
        verdict = ("OUTSIDE the prior's span (the reconstruction is the prior's nearest guess: measure densely)"
                   if self.out_of_span else "consistent with the prior")
        return (f"fit quality: {self.n_samples} samples, χ²/dof = {self.chi2 / max(self.dof, 1):.3g} "
                f"({self.dof} dof, p = {self.p_value:.2g}): {verdict}")


@dataclass(frozen=True, eq=False)
class Posterior:
    """The posterior over a material given samples (module docstring). Build with :meth:`start`, add samples
    with :meth:`update` (returns a new posterior; the old one is unchanged)."""

    prior: Prior
    precision: np.ndarray  # (3, K, K)
    info: np.ndarray  # (3, K)
    n_samples: int = 0
    #: the observations so far, chunks of (A (n, K), y − Hμ (n, 3), v (n, 3)), for :meth:`quality`
    observations: tuple = ()

    @classmethod
    def start(cls, prior: Prior) -> "Posterior":
        """The prior itself, before any sample."""
        k = prior.n_components
        p = np.broadcast_to(np.diag(1.0 / np.maximum(prior.variance, 1e-300)), (3, k, k)).copy()
        return cls(prior, p, np.zeros((3, k)))

    def update(self, wi, wo, f, sigma, *, source: str = "samples") -> "Posterior":
        """The posterior after samples ``f`` ± ``sigma`` (1/sr, (n, 3)) at ``wi``, ``wo`` (n, 3) are added.
        Non-finite values or σ ≤ 0 are refused (:class:`DataError` naming the sample)."""
        wi, wo, f, sigma = _check_samples(wi, wo, f, sigma, source)
        if len(wi) == 0:
            return self
        pr = self.prior
        h, a, fref = observation_rows(pr, wi, wo)
        y = to_mapped(f, fref, pr.eps) - (h @ pr.mean)[:, None]  # (n, 3)
        su = sigma_to_mapped(f, sigma, pr.eps)
        # the residual is shared by samples with the same nearest node (module docstring)
        nearest = np.asarray(h.argmax(axis=1)).ravel()
        _, inv, counts = np.unique(nearest, return_inverse=True, return_counts=True)
        v = su ** 2 + (counts[inv] * (h @ pr.residual))[:, None]
        v = np.maximum(v, 1e-300)
        prec = self.precision.copy()
        info = self.info.copy()
        for c in range(3):
            aw = a / v[:, c:c + 1]
            prec[c] += a.T @ aw
            info[c] += aw.T @ y[:, c]
        return Posterior(pr, prec, info, self.n_samples + len(wi), self.observations + ((a, y, v),))

    def update_samples(self, samples, *, source: str = "samples") -> "Posterior":
        """:meth:`update` with a :class:`gonio.samples.SampleSet`."""
        return self.update(samples.wi, samples.wo, samples.f, samples.sigma, source=source)

    # -- the Gaussian over coefficients ----------------------------------------------------------
    def _chol(self):
        cached = self.__dict__.get("_chol_cache")
        if cached is None:
            cached = np.linalg.cholesky(self.precision)
            object.__setattr__(self, "_chol_cache", cached)
        return cached

    @property
    def coefficients(self) -> np.ndarray:
        """Posterior mean of the coefficients, (3, K)."""
        l = self._chol()
        z = np.linalg.solve(l, self.info[..., None])
        return np.linalg.solve(np.swapaxes(l, -1, -2), z)[..., 0]

    @property
    def covariance(self) -> np.ndarray:
        """Posterior covariance of the coefficients, (3, K, K)."""
        linv = np.linalg.inv(self._chol())
        return np.swapaxes(linv, -1, -2) @ linv

    # -- reconstruction ----------------------------------------------------------------------------
    def node_mapped(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and standard deviation of u at every node, each (3, G) (computed once per posterior)."""
        cached = self.__dict__.get("_node_cache")
        if cached is not None:
            return cached
        pr = self.prior
        mean = pr.node_mapped(self.coefficients)
        linv = np.linalg.inv(self._chol())  # S = L⁻ᵀ L⁻¹ → diag(B S Bᵀ) = ‖L⁻¹ Bᵀ‖² per node
        var = np.stack([np.sum((linv[c] @ pr.basis.T) ** 2, axis=0) for c in range(3)]) + pr.residual[None, :]
        out = (mean, np.sqrt(var))
        for a in out:
            a.setflags(write=False)
        object.__setattr__(self, "_node_cache", out)
        return out

    def predict(self, wi, wo) -> tuple[np.ndarray, np.ndarray]:
        """Posterior BRDF (1/sr) and its standard uncertainty at direction pairs, each (n, 3); both 0 below
        the horizon (module docstring)."""
        w = cos_weight(np.reshape(wi, (-1, 3)), np.reshape(wo, (-1, 3)))
        return self._predict(self.prior.grid.weights(wi, wo), w > 0)

    def _predict(self, h, above) -> tuple[np.ndarray, np.ndarray]:
        mean, sd = self.node_mapped()
        f = from_mapped(h @ mean.T, h @ self.prior.f_ref, self.prior.eps)
        s = sigma_from_mapped(f, h @ sd.T, self.prior.eps)
        above = np.asarray(above)[:, None]
        return np.where(above, f, 0.0), np.where(above, s, 0.0)

    def table(self):
        """The reconstruction on the MERL grid: a :class:`gonio.io.merl.MerlTable` with ``values`` and
        ``sigma`` in every cell above the horizon (NaN below it, as MERL files mark them)."""
        from gonio.io.merl import SHAPE, MerlTable
        from gonio.prior.grid import merl_above

        above = merl_above()
        values = np.full(SHAPE + (3,), np.nan)
        sigma = np.full(SHAPE + (3,), np.nan)
        h = self.prior.grid.weights_merl()
        values[above], sigma[above] = self._predict(h, np.ones(h.shape[0], dtype=bool))
        return MerlTable(values, sigma)

    # -- errors and diagnostics --------------------------------------------------------------------
    def _error_matrix(self) -> np.ndarray:
        cached = self.prior.__dict__.get("_error_matrix")
        if cached is None:
            b = self.prior.basis
            cached = b.T @ (b * self.prior.weight[:, None])
            object.__setattr__(self.prior, "_error_matrix", cached)
        return cached

    def expected_error(self) -> float:
        """Expected RMS error of u over the valid MERL cells, averaged over channels (module docstring)."""
        m = self._error_matrix()
        cov = self.covariance
        q = self.prior.weight
        per = [np.sum(m * cov[c]) for c in range(3)]
        return float(np.sqrt((np.mean(per) + np.sum(q * self.prior.residual)) / np.sum(q)))

    def expected_error_after(self, wi, wo, sigma_u=0.0, *, n_samples=1) -> np.ndarray:
        """Expected error (:meth:`expected_error`) after adding *one* candidate direction pair, for each of
        the candidates ``wi``, ``wo`` (n, 3): the rank-one update of S (Sherman–Morrison), vectorized.
        ``sigma_u``: the candidate's expected noise in the mapped domain (scalar or (n,)); ``n_samples``: how
        many samples one candidate gives (their noise averages, the residual does not)."""
        m = self._error_matrix()
        cov = self.covariance
        q = self.prior.weight
        total = sum(np.sum(m * cov[c]) for c in range(3))
        out = total - self.error_reduction(wi, wo, sigma_u, n_samples=n_samples)
        return np.sqrt((out / 3 + np.sum(q * self.prior.residual)) / np.sum(q))

    def cbrt_weight(self) -> np.ndarray:
        """Per-channel node weights (3, G) that turn an error of u into the cube-root error of
        :func:`gonio.fit.metrics.cbrt_error` (Ngan et al. 2005's cube-root cosine-weighted RMS): linearised,
        δ∛(f·cos θi) = ⅓·cos^⅓θi·f^(−⅔)·(f + ε)·δu ≈ ⅓·cos^⅓θi·(f + ε)^⅓·δu where f ≫ ε, so a node weighs its share
        of the MERL cells × cos^⅔θi × (f̂ + ε)^⅔ with f̂ the posterior's value there (:meth:`node_mapped`, mapped
        back) — bright directions (a specular peak) count more than dark ones, and *which* are bright is learnt
        from the samples. cos θi is the node's own (φh = 0)."""
        pr = self.prior
        cached = pr.__dict__.get("_cos_i_23")
        if cached is None:
            wi, _ = pr.grid.node_directions()
            cached = np.clip(wi[:, 2], 0.0, None) ** (2.0 / 3.0)
            object.__setattr__(pr, "_cos_i_23", cached)
        mean, _ = self.node_mapped()
        f = from_mapped(mean, pr.f_ref[None, :], pr.eps)
        return pr.weight[None, :] * cached[None, :] * (f + pr.eps) ** (2.0 / 3.0)

    def error_reduction(self, wi, wo, sigma_u, *, n_samples=1, node_weight=None) -> np.ndarray:
        """For each candidate direction pair (n, 3): how much adding it reduces the expected weighted squared
        error Σ_c Σ_g w_cg·Var(u_cg) (exact rank-one update per channel, as :meth:`expected_error_after`);
        ``node_weight`` (3, G), default the cells' shares (:meth:`expected_error`'s measure), e.g.
        :meth:`cbrt_weight`. ``sigma_u`` scalar, (n,) or (n, 3)."""
        pr = self.prior
        h, a, _ = observation_rows(pr, wi, wo)
        su = np.broadcast_to(np.asarray(sigma_u, dtype=np.float64).reshape(-1, 1) if np.ndim(sigma_u) == 1
                             else np.asarray(sigma_u, dtype=np.float64), (len(a), 3))
        v = su ** 2 / np.reshape(n_samples, (-1, 1)) + (h @ pr.residual)[:, None]
        w = np.broadcast_to(pr.weight, (3, pr.grid.size)) if node_weight is None else np.asarray(node_weight)
        cov = self.covariance
        out = np.zeros(len(a))
        for c in range(3):
            m = pr.basis.T @ (pr.basis * w[c][:, None])
            ps = a @ cov[c]
            out += np.sum((ps @ m) * ps, axis=1) / np.maximum(v[:, c] + np.sum(ps * a, axis=1), 1e-300)
        return out

    def quality(self) -> Quality:
        """The consistency χ² of the samples with the prior (module docstring)."""
        from scipy.special import chdtrc  # χ²'s survival function: scipy.stats.chi2.sf's, without importing scipy.stats

        m = self.coefficients
        x2 = float(np.sum(m * m / np.maximum(self.prior.variance, 1e-300)))
        for a, y, v in self.observations:
            x2 += float(np.sum((y - a @ m.T) ** 2 / v))
        dof = 3 * self.n_samples
        p = float(chdtrc(dof, x2)) if dof else 1.0
        return Quality(self.n_samples, x2, dof, p)
