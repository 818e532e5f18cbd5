"""Data-driven BRDF priors: learn from measured materials, plan a few poses, reconstruct a whole table.

The method (docs/prior.md): Nielsen, Jensen & Ramamoorthi 2015's log-relative mapping and principal
components, made a Bayesian linear model with each sample's own σ, leave-one-out calibrated variances, a
per-direction residual (a material outside the prior's span is said, not forced into it) and A-optimal
pose selection within the rig's reach.

Public API (one concept per module):

* :class:`PriorGrid` (:mod:`.grid`) — the (θh, θd, φd) nodes the prior lives on and trilinear weights.
* :mod:`.mapping` — u = ln((f·w + ε)/(f_ref·w + ε)) and its delta-method σ, both ways.
* :class:`Prior`, :func:`load_prior`, :func:`save_prior`, :func:`default_prior` (:mod:`.model`) — the data
  type and its versioned ``.npz`` format (docs/formats.md).
* :func:`build_prior` (node values), :func:`build_from_sources` (anything :func:`gonio.load` reads)
  (:mod:`.build`).
* :class:`Posterior` (:mod:`.posterior`) — ``Posterior.start(prior).update(wi, wo, f, sigma)`` (or
  ``.update_samples(SampleSet)``), then ``.table()`` (MerlTable with σ), ``.predict(wi, wo)``,
  ``.expected_error()``, ``.expected_error_after(wi, wo, sigma_u)`` (per candidate, for choosing the next
  pose), ``.quality()`` (consistency χ², out-of-span verdict).
* :func:`select_directions`, :func:`candidate_poses`, :func:`sparse_plan` (:mod:`.design`) — greedy A-optimal
  poses within the rig's reach, and the :class:`gonio.plan.Plan` that measures them.
* :func:`reconstruct` (:mod:`.reconstruct`) — a source's samples → Posterior, with the checks the CLI makes.
* :mod:`.nielsen` — Nielsen et al. 2015 as published (condition-number directions, ridge regression), the
  baseline ``benchmarks sparse`` compares with.
"""

from __future__ import annotations

from gonio.prior.build import build_from_sources, build_prior, node_values
from gonio.prior.grid import DEFAULT_GRID, PriorGrid
from gonio.prior.model import FORMAT_VERSION, Prior, default_prior, default_prior_path, load_prior, save_prior
from gonio.prior.posterior import Posterior, Quality

__all__ = ["PriorGrid", "DEFAULT_GRID", "Prior", "FORMAT_VERSION", "load_prior", "save_prior", "default_prior",
           "default_prior_path", "build_prior", "build_from_sources", "node_values", "Posterior", "Quality"]
