"""The MERL reference reader's cell lookup, reproduced bit for bit.

The MERL BRDF database ships one reader, ``BRDFRead.cpp`` (Matusik, Pfister, Brand, McMillan, "A
Data-Driven Reflectance Model", SIGGRAPH 2003; MERL 2005). A table cell is what that program's
``lookup_brdf_val`` reads, so a lookup that claims to be "the MERL lookup" must land in the same cell
for every direction pair, boundaries included. This module follows its arithmetic operation by
operation, in float64, in the same order:

``std_coords_to_half_diff_coords``
    ``in = normalize(v_i)`` (the unnormalized ``v_i`` is what enters the half vector),
    ``half = normalize((v_i + v_o) / 2)``, ``θh = acos(half_z)``, ``φh = atan2(half_y, half_x)``,
    ``diff = rotate_vector(rotate_vector(in, z, −φh), y, −θh)`` with Rodrigues' formula written as
    ``v cos a + axis (axis·v)(1 − cos a) + (axis × v) sin a`` (including the products by the zero
    components of the axis, which decide the sign of zero results), ``θd = acos(diff_z)``,
    ``φd = atan2(diff_y, diff_x)`` in (−π, π].

``theta_half_index``
    0 if θh ≤ 0, else ``(int) sqrt(((θh / (π/2)) · 90) · 90)`` clamped to [0, 89].
``theta_diff_index``
    ``(int) (θd / (π · 0.5) · 90)`` clamped to [0, 89].
``phi_diff_index``
    φd += π if φd < 0 (reciprocity), then ``(int) (φd / π · 360 / 2)`` clamped to [0, 179]: so φd = π
    (an in-plane pair on opposite sides) is cell 179 and φd = −π or 0 is cell 0.

``(int)`` truncates toward zero (a NaN converts to INT_MIN on x86-64 and is clamped to 0).

Exactness: + − × / and sqrt are correctly rounded in IEEE 754 and so identical in NumPy and C;
acos/atan2/cos/sin are not (NumPy's SIMD versions differ from the C library's in the last bits). The
vectorized pass uses NumPy's; every pair whose result could depend on those last bits (a
pre-truncation value within 1e-6 of an integer, or a difference vector within 1e-6 of the pole, where
φd is ill-conditioned: wi = wo, exact in-plane pairs) is recomputed with the C library's functions
(Python's ``math`` module wraps them), the ones the reference program calls — one Python call per value, or
the same C functions in a compiled loop (:mod:`gonio.io._libm`, checked against ``math`` bit for bit before it is
used) once a process computed :data:`COLD_VALUES` values.
"""

from __future__ import annotations

import functools
import math
import sys

import numpy as np

__all__ = ["reference_half_diff", "reference_index", "half_diff_index", "directions_from_angles"]

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
#: Resolution constant of the reference program (``BRDF_SAMPLING_RES_PHI_D``; the table holds half).
_RES_PHI_D = 360
_M_PI = 3.1415926535897932384626433832795  # M_PI_LOCAL of the reference; == math.pi as a double
_TOL = 1e-6


#: :func:`_libm` runs the C library's functions in a compiled loop (:mod:`gonio.io._libm`, ~25 ns a value instead of
#: the ~0.6 µs of a Python call) on calls of this many values or more once numba is in this process (loading the
#: loop then costs ~0.02 CPU s) ...
MIN_COMPILED = 64
#: ... and, before that, loads numba and the loop (~0.5 CPU s) once the Python path has computed this many values in
#: this process (about as much time as the load; a renter who buys once the rent paid reaches the price pays at most
#: twice the better of the two: Karlin et al., "Competitive snoopy caching", Algorithmica 3, 1988), or for a single
#: call this large. E.g. a sphere rendered from a MERL table with the light along the view: wi = wo at every pixel,
#: every pair near the pole and recomputed, ~8 values a pixel.
COLD_VALUES = 1_000_000
_PYTHON_VALUES = [0]  #: values the Python path computed in this process (:data:`COLD_VALUES`)


@functools.lru_cache(maxsize=1)
def _compiled():
    """:data:`gonio.io._libm.FUNCTIONS` if numba is installed, not disabled (``GONIO_BRDF_BACKEND=numpy``) and its
    loops give :mod:`math`'s results bit for bit (:func:`gonio.io._libm.exact`); else None."""
    import os

    from gonio.brdf import compiled

    if not compiled.available() or os.environ.get("GONIO_BRDF_BACKEND", "").lower() == "numpy":
        return None
    from gonio.io import _libm as lib

    return lib.FUNCTIONS if lib.exact() else None


def _warm() -> bool:
    """The loop is loaded, or numba is in this process (loading the loop costs little then)."""
    return bool(_compiled.cache_info().currsize) or "numba" in sys.modules


def _loops(n: int):
    """The compiled loops for a call on ``n`` values (:data:`MIN_COMPILED`, :data:`COLD_VALUES`), or None: the
    Python path (which counts them)."""
    if n >= MIN_COMPILED and (_warm() or _PYTHON_VALUES[0] + n >= COLD_VALUES):
        loops = _compiled()
        if loops is not None:
            return loops
    _PYTHON_VALUES[0] += n
    return None


def _libm(f, nargs: int = 1):
    """``f`` (a C library function wrapped by :mod:`math`) applied elementwise, float64 out: one Python call per
    value, or the same C function in a compiled loop (:func:`_loops`)."""
    u = np.frompyfunc(f, nargs, 1)
    name = f.__name__

    def call(*args):
        args = [np.asarray(a, dtype=np.float64) for a in args]
        shape = np.broadcast_shapes(*(a.shape for a in args))
        loops = _loops(math.prod(shape))
        if loops is not None:
            flat = [np.array(np.broadcast_to(a, shape), dtype=np.float64, order="C").ravel() for a in args]
            return loops[name](*flat).reshape(shape)
        with np.errstate(invalid="ignore"):
            return np.asarray(u(*args), dtype=np.float64)

    return call


def _c_call(f):
    """``f`` returning NaN where :mod:`math` raises and C returns NaN (acos(1 + ε), cos(inf), NaN in)."""

    def call(*args):
        try:
            return f(*args)
        except ValueError:
            return math.nan

    call.__name__ = f.__name__
    return call


_LIBM = {"cos": _libm(_c_call(math.cos)), "sin": _libm(_c_call(math.sin)), "acos": _libm(_c_call(math.acos)),
         "atan2": _libm(_c_call(math.atan2), 2)}
_NUMPY = {"cos": np.cos, "sin": np.sin, "acos": np.arccos, "atan2": np.arctan2}


def _normalize(v):
    length = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return [v[0] / length, v[1] / length, v[2] / length]


def _rotate(v, axis, cos_ang, sin_ang):
    """``rotate_vector`` of the reference, with a constant axis (its zero components multiply too)."""
    out = [v[0] * cos_ang, v[1] * cos_ang, v[2] * cos_ang]
    temp = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]
    temp = temp * (1.0 - cos_ang)
    out = [out[0] + axis[0] * temp, out[1] + axis[1] * temp, out[2] + axis[2] * temp]
    cross = [axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2], axis[0] * v[1] - axis[1] * v[0]]
    return [out[0] + cross[0] * sin_ang, out[1] + cross[1] * sin_ang, out[2] + cross[2] * sin_ang]


def _half_diff(vi, vo, fn):
    """The reference's std_coords_to_half_diff_coords from its two (unnormalized) vectors."""
    in_ = _normalize(vi)
    half = _normalize([(vi[0] + vo[0]) / 2.0, (vi[1] + vo[1]) / 2.0, (vi[2] + vo[2]) / 2.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        theta_half = fn["acos"](half[2])
        fi_half = fn["atan2"](half[1], half[0])
        temp = _rotate(in_, (0.0, 0.0, 1.0), fn["cos"](-fi_half), fn["sin"](-fi_half))
        diff = _rotate(temp, (0.0, 1.0, 0.0), fn["cos"](-theta_half), fn["sin"](-theta_half))
        theta_diff = fn["acos"](diff[2])
        fi_diff = fn["atan2"](diff[1], diff[0])
    return theta_half, fi_half, theta_diff, fi_diff, diff


def _truncate(x) -> np.ndarray:
    """C's ``(int) x`` for x in int range; NaN → INT_MIN as on x86-64 (callers clamp it to 0)."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(x), np.trunc(np.nan_to_num(x)), -(2.0 ** 31))


def _pre_truncation(theta_half, theta_diff, phi_diff):
    """The three values the reference truncates to integers (φd folded as it folds it)."""
    with np.errstate(invalid="ignore"):
        u_h = np.sqrt(((theta_half / (_M_PI / 2.0)) * N_THETA_H) * N_THETA_H)
        u_d = theta_diff / (_M_PI * 0.5) * N_THETA_D
        p = np.where(phi_diff < 0.0, phi_diff + _M_PI, phi_diff)
        u_p = p / _M_PI * _RES_PHI_D / 2
    return u_h, u_d, u_p


def half_diff_index(theta_half, theta_diff, phi_diff) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(theta_half_index, theta_diff_index, phi_diff_index)`` of the reference, vectorized and exact.

    ``phi_diff`` is taken in the reference's range (−π, π]; a value in (π, 2π) (the range of
    :func:`gonio.geometry.half_diff_from_dirs`) is first moved down by 2π (the same direction).
    """
    th = np.asarray(theta_half, dtype=np.float64)
    td = np.asarray(theta_diff, dtype=np.float64)
    pd = np.asarray(phi_diff, dtype=np.float64)
    pd = np.where(pd > _M_PI, pd - 2.0 * _M_PI, pd)
    u_h, u_d, u_p = _pre_truncation(th, td, pd)
    i_h = np.where(th <= 0.0, 0.0, _truncate(u_h))
    i_d = _truncate(u_d)
    i_p = _truncate(u_p)
    return (np.clip(i_h, 0, N_THETA_H - 1).astype(np.intp), np.clip(i_d, 0, N_THETA_D - 1).astype(np.intp),
            np.clip(i_p, 0, N_PHI_D - 1).astype(np.intp))


def _near_integer(u) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return ~np.isfinite(u) | (np.abs(u - np.round(u)) <= _TOL * np.maximum(1.0, np.abs(u)))


def reference_half_diff(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(θh, φh, θd, φd)`` exactly as the reference computes them from vectors ``wi``, ``wo`` (..., 3).

    φh and φd are in (−π, π] (``atan2``). Where the NumPy pass could differ from the C library in a
    way that changes a cell (module docstring), the C library's values are returned.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    wi, wo = np.broadcast_arrays(wi, wo)
    shape = wi.shape[:-1]
    vi = [wi[..., k].ravel() for k in range(3)]
    vo = [wo[..., k].ravel() for k in range(3)]
    th, ph, td, pd, diff = _half_diff(vi, vo, _NUMPY)
    with np.errstate(invalid="ignore"):
        pole = np.hypot(diff[0], diff[1]) <= _TOL
    u = _pre_truncation(th, td, pd)
    suspect = pole | _near_integer(u[0]) | _near_integer(u[1]) | _near_integer(u[2])
    if suspect.any():
        idx = np.nonzero(suspect)[0]
        exact = _half_diff([c[idx] for c in vi], [c[idx] for c in vo], _LIBM)
        for arr, val in zip((th, ph, td, pd), exact[:4]):
            arr[idx] = val
    return th.reshape(shape), ph.reshape(shape), td.reshape(shape), pd.reshape(shape)


def reference_index(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell indices ``(iθh, iθd, iφd)`` the reference's ``lookup_brdf_val`` reads for ``wi``, ``wo``."""
    th, _, td, pd = reference_half_diff(wi, wo)
    return half_diff_index(th, td, pd)


def directions_from_angles(theta_in, phi_in, theta_out, phi_out) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)`` (..., 3) built from angles as the reference builds them (C library cos/sin):
    ``(sin θ cos φ, sin θ sin φ, cos θ)``, so a lookup by angles equals ``lookup_brdf_val`` by angles."""
    def per_value(name, x):  # angles repeat on grids: one C call per distinct value
        u, inv = np.unique(x, return_inverse=True)
        return _LIBM[name](u)[inv].reshape(x.shape)

    out = []
    for t, p in ((theta_in, phi_in), (theta_out, phi_out)):
        t, p = np.broadcast_arrays(np.asarray(t, dtype=np.float64), np.asarray(p, dtype=np.float64))
        z = per_value("cos", t)
        s = per_value("sin", t)
        out.append(np.stack([s * per_value("cos", p), s * per_value("sin", p), z], axis=-1))
    return out[0], out[1]
