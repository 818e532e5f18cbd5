"""Plots of measured BRDFs: polar slice at fixed incidence, in-plane curve with error bars and a model,
coverage of the sampled directions, residuals after a fit. PNG through matplotlib's Agg canvas
(headless; no pyplot, no global backend state). matplotlib is the optional extra ``plots`` and is
imported inside the functions only.

Every function returns a :class:`matplotlib.figure.Figure`; :func:`save` writes it. A ``title`` (a file
or directory name, usually) is drawn as written: never parsed as mathtext (a ``$`` in a name is a dollar
sign, not a formula that fails to draw); in an SVG, matplotlib's writer escapes it (XML text and comments).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gonio.errors import ConfigError, DataError
from gonio.geometry import from_spherical, half_diff_from_dirs
from gonio.samples import SampleSet

__all__ = ["INSTALL_HINT", "figure", "save", "polar_slice", "inplane", "coverage", "residual"]

INSTALL_HINT = "plots need matplotlib: pip install 'gonio[plots]'"
_RGB = ("tab:red", "tab:green", "tab:blue")


def figure(width: float = 7.0, height: float = 5.0):
    """A new Figure attached to an Agg canvas; :class:`ConfigError` with the install hint if no matplotlib."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ConfigError(INSTALL_HINT) from None
    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save(fig, path) -> Path:
    """Write ``fig`` as PNG (or any format matplotlib knows from the suffix)."""
    path = Path(path)
    try:
        fig.savefig(path)
    except OSError as exc:
        raise DataError(f"{path}: cannot write plot ({exc.strerror or exc})") from None
    return path


def _incidence(samples: SampleSet, theta_i_deg: float | None, tol_deg: float, what: str) -> np.ndarray:
    """Mask of samples whose θi is within ``tol_deg`` of ``theta_i_deg`` (default: the most frequent θi)."""
    ti = np.degrees(samples.angles()[0])
    if len(ti) == 0:
        raise DataError(f"{what}: no samples to plot")
    if theta_i_deg is None:
        vals, counts = np.unique(np.round(ti), return_counts=True)
        theta_i_deg = float(vals[np.argmax(counts)])
    mask = np.abs(ti - theta_i_deg) <= tol_deg
    if not mask.any():
        avail = ", ".join(f"{v:g}" for v in np.unique(np.round(ti))[:12])
        raise DataError(f"{what}: no samples within {tol_deg:g} deg of theta_i = {theta_i_deg:g} deg "
                        f"(measured theta_i, deg: {avail}{' ...' if len(np.unique(np.round(ti))) > 12 else ''})")
    return mask


def _require_positive(values: np.ndarray, what: str, hint: str = "") -> None:
    """A log-scale plot of a table with no positive value would show a uniform floor: refuse it."""
    if not np.any(np.nan_to_num(values, nan=0.0) > 0):
        raise DataError(f"{what}: the table holds no positive value here (all zero or not measured): "
                        f"nothing to show on a log scale{hint}")


#: Said under a polar map's title: the rings' values are not written inside the disc, over the data.
RINGS = "rings at θ = 30°, 60°, 90°"


def _polar_axis_style(ax) -> None:
    """θ rings every 30°, unlabelled (their values are in the title: :data:`RINGS`), so no label sits
    over the data; small φ labels outside the disc."""
    ax.set_rlim(0, 90)
    ax.set_rticks([30, 60, 90])
    ax.set_yticklabels([])
    ax.tick_params(axis="x", labelsize=7, pad=1)


def _relative_azimuth(samples: SampleSet) -> np.ndarray:
    _, pi_, _, po = samples.angles()
    return np.mod(po - pi_, 2 * np.pi)


def in_plane(samples: SampleSet, theta_i_deg: float | None = None, tol_deg: float = 2.5):
    """``(mask, signed θo in degrees)`` of the samples in the plane of incidence: φo − φi within
    ``tol_deg`` of 0 or 180° (or θo within ``tol_deg`` of the normal, where φo means nothing) and, with
    ``theta_i_deg``, θi within ``tol_deg`` of it. θo is positive on the specular side (φo − φi = 180°),
    as in :func:`inplane_dirs`."""
    ti, _, to, _ = samples.angles()
    dphi = _relative_azimuth(samples)
    mask = (np.abs(np.sin(dphi)) <= np.sin(np.radians(tol_deg))) | (to < np.radians(tol_deg))
    if theta_i_deg is not None:
        mask &= np.abs(np.degrees(ti) - theta_i_deg) <= tol_deg
    return mask, np.degrees(to) * np.where(np.cos(dphi) < 0, 1.0, -1.0)


def polar_slice(*, samples: SampleSet | None = None, table=None, theta_i_deg: float | None = None,
                tol_deg: float = 2.5, title: str = ""):
    """2-D slice of the BRDF at fixed incidence (like the lecture notes' "PVC BRDF at 55° incidence",
    ``004_6b0fa14dcb48ed2f.txt``): outgoing θo as radius, φo − φi as angle, colour log10 of the
    channel-mean BRDF (1/sr). Samples are scattered points; a table is drawn as a filled map."""
    fig = figure(6.5, 5.5)
    ax = fig.add_subplot(projection="polar")
    if samples is not None:
        mask = _incidence(samples, theta_i_deg, tol_deg, title or "polar plot")
        s = samples.subset(mask)
        ti = float(np.degrees(np.median(s.angles()[0]))) if theta_i_deg is None else theta_i_deg
        val = s.f.mean(axis=1)
        art = ax.scatter(_relative_azimuth(s), np.degrees(s.angles()[2]), c=np.log10(np.maximum(val, 1e-6)),
                         s=14, cmap="viridis")
    elif table is not None:
        ti = 45.0 if theta_i_deg is None else theta_i_deg
        to, dphi = np.meshgrid(np.radians(np.arange(0.5, 89, 1.0)), np.radians(np.arange(0, 361, 2.0)), indexing="ij")
        wi = from_spherical(np.radians(ti), 0.0)
        val = table.lookup(np.broadcast_to(wi, to.shape + (3,)), from_spherical(to, dphi), "trilinear").mean(axis=-1)
        _require_positive(val, title or "polar plot")
        art = ax.pcolormesh(dphi, np.degrees(to), np.log10(np.maximum(val, 1e-6)), shading="auto", cmap="viridis")
    else:
        raise ValueError("polar_slice needs samples or a table")
    _polar_axis_style(ax)
    ax.set_title(f"{title + ': ' if title else ''}BRDF at {ti:.1f}° incidence\n(radius θo, {RINGS}; angle φo − φi)",
                 parse_math=False)
    fig.colorbar(art, ax=ax, label="log10 BRDF (1/sr), mean of R,G,B", shrink=0.8)
    return fig


def inplane_dirs(theta_i_deg: float, signed_theta_o_deg: np.ndarray):
    """wi at (θi, φ=0); wo in the incidence plane, positive θo on the specular side (φo = π)."""
    t = np.radians(signed_theta_o_deg)
    wo = from_spherical(np.abs(t), np.where(t >= 0, np.pi, 0.0))
    return np.broadcast_to(from_spherical(np.radians(theta_i_deg), 0.0), wo.shape), wo


def inplane(*, samples: SampleSet | None = None, table=None, model=None, theta_i_deg: float | None = None,
            tol_deg: float = 2.5, log: bool = True, title: str = ""):
    """BRDF in the plane of incidence versus signed θo (positive on the specular side): measured points
    with ±1σ error bars per channel, and ``model`` (a :class:`gonio.brdf.BRDF`) or the table overlaid."""
    fig = figure(7.5, 5.0)
    ax = fig.add_subplot()
    if samples is not None:
        mask = _incidence(samples, theta_i_deg, tol_deg, title or "in-plane plot")
        plane, signed = in_plane(samples, None, tol_deg)
        if not (mask & plane).any():
            raise DataError(f"{title or 'in-plane plot'}: no samples in the plane of incidence "
                            f"(within {tol_deg:g} deg)")
        s, x = samples.subset(mask & plane), signed[mask & plane]
        if theta_i_deg is None:
            theta_i_deg = float(np.round(np.degrees(np.median(s.angles()[0]))))
        order = np.argsort(x)
        for c, colour in enumerate(_RGB):
            ax.errorbar(x[order], s.f[order, c], yerr=s.sigma[order, c], fmt="o", ms=3, color=colour,
                        capsize=2, label=f"measured {'RGB'[c]}")
    theta_i_deg = 45.0 if theta_i_deg is None else theta_i_deg
    grid = np.linspace(-89, 89, 357)
    wi, wo = inplane_dirs(theta_i_deg, grid)
    if table is not None:
        v = table.lookup(wi, wo, "trilinear")
        if log:
            _require_positive(v, title or "in-plane plot", hint="; try --linear")
        for c, colour in enumerate(_RGB):
            ax.plot(grid, v[:, c], "-", color=colour, lw=1.0, alpha=0.6 if model is not None else 1.0,
                    label=f"table {'RGB'[c]}")
    if model is not None:
        v = model.eval(wi, wo)
        for c, colour in enumerate(_RGB):
            ax.plot(grid, v[:, c], "--", color=colour, lw=1.5, label=f"{model.name} {'RGB'[c]}")
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("θo (deg), positive on the specular side")
    ax.set_ylabel("BRDF (1/sr)")
    ax.set_xlim(-90, 90)
    ax.axvline(theta_i_deg, color="0.6", lw=0.8, ls=":")
    ax.set_title(f"{title + ': ' if title else ''}plane of incidence, θi = {theta_i_deg:.1f}°", parse_math=False)
    ax.legend(fontsize=7, ncol=3)
    return fig


def coverage(*, samples: SampleSet | None = None, table=None, title: str = ""):
    """Coverage of the sampled directions: wi and wo on polar maps (radius θ, angle φ) and the sample
    count over (θh, θd); for a table, the fraction of measured φd cells over (θh, θd)."""
    if samples is not None:
        fig = figure(12.0, 4.2)
        ti, pi_, to, po = samples.angles()
        for k, (t, p, name) in enumerate(((ti, pi_, "wi (light)"), (to, po, "wo (camera)"))):
            ax = fig.add_subplot(1, 3, k + 1, projection="polar")
            ax.scatter(p, np.degrees(t), s=3, alpha=0.5, color=("tab:orange", "tab:blue")[k])
            _polar_axis_style(ax)
            ax.set_title(f"{name}: {len(t)} samples\n{RINGS}", pad=14, fontsize=10)
        th, _, td, _ = half_diff_from_dirs(samples.wi, samples.wo)
        ax = fig.add_subplot(1, 3, 3)
        _, _, _, img = ax.hist2d(np.degrees(td), np.degrees(th), bins=[45, 45], range=[[0, 90], [0, 90]],
                                 cmap="magma", cmin=1)
        fig.colorbar(img, ax=ax, label="samples")
        ax.set_xlabel("θd (deg)")
        ax.set_ylabel("θh (deg)")
    elif table is not None:
        fig = figure(6.0, 5.0)
        ax = fig.add_subplot()
        frac = table.measured.mean(axis=2)
        img = ax.imshow(frac, origin="lower", aspect="auto", cmap="magma", vmin=0, vmax=1,
                        extent=(0, 90, 0, 90))
        fig.colorbar(img, ax=ax, label="fraction of φd cells measured")
        ax.set_xlabel("θd (deg)")
        ax.set_ylabel("θh cell index (sqrt mapping)")
        ax.set_title(f"{int(table.measured.sum())} of {table.measured.size} cells measured")
    else:
        raise ValueError("coverage needs samples or a table")
    if title:
        fig.suptitle(title, parse_math=False)
    return fig


def residual(*, samples: SampleSet, model, title: str = ""):
    """Normalized residuals ``(f − model)/σ`` (mean over R,G,B) after a fit: a map over (θd, θh) and
    their histogram with the standard normal for comparison."""
    fig = figure(11.0, 4.5)
    pred = model.eval(samples.wi, samples.wo)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(samples.sigma > 0, (samples.f - pred) / samples.sigma, np.nan).mean(axis=1)
    ok = np.isfinite(r)
    if not ok.any():
        raise DataError(f"{title or 'residual plot'}: no sample with a positive uncertainty")
    th, _, td, _ = half_diff_from_dirs(samples.wi[ok], samples.wo[ok])
    ax = fig.add_subplot(1, 2, 1)
    lim = max(3.0, float(np.percentile(np.abs(r[ok]), 98)))
    art = ax.scatter(np.degrees(td), np.degrees(th), c=r[ok], cmap="RdBu_r", vmin=-lim, vmax=lim, s=6)
    fig.colorbar(art, ax=ax, label="(f − model) / σ")
    ax.set_xlabel("θd (deg)")
    ax.set_ylabel("θh (deg)")
    rms = float(np.sqrt(np.mean(r[ok] ** 2)))
    ax.set_title(f"residuals of {model.name}: RMS {rms:.3g} σ over {int(ok.sum())} samples", parse_math=False)
    ax = fig.add_subplot(1, 2, 2)
    ax.hist(np.clip(r[ok], -4 * lim, 4 * lim), bins=60, density=True, color="0.5")
    x = np.linspace(-4 * lim, 4 * lim, 200)
    ax.plot(x, np.exp(-0.5 * x**2) / np.sqrt(2 * np.pi), "k--", lw=1, label="N(0, 1)")
    ax.set_xlabel("(f − model) / σ")
    ax.set_ylabel("probability density")
    ax.legend()
    if title:
        fig.suptitle(title, parse_math=False)
    return fig
