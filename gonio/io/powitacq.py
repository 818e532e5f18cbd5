"""The RGL material database's ``.bsdf`` files: Dupuy & Jakob, "An Adaptive Parameterization for
Efficient Material Acquisition and Rendering", ACM TOG 37(6), 2018 (the ``powitacq`` format and its
reference evaluation, ``powitacq_rgb.h``/``.inl`` of the RGL brdf-loader).

File (a "tensor file", all little-endian)::

    "tensor_file\\0" (12 bytes), version (2 × uint8: 1, 0), n_fields (uint32), then per field:
    name_length (uint16), name (bytes), ndim (uint16), dtype (uint8: 1 u8, 2 i8, 3 u16, 4 i16, 5 u32,
    6 i32, 7 u64, 8 i64, 9 f16, 10 f32, 11 f64), offset (uint64, from the file start),
    shape (ndim × uint64); the field's data (C order) at ``offset``.

Fields used (float32 unless said): ``theta_i`` (n_θ) and ``phi_i`` (n_φ) — the incidence grid;
``ndf`` (2-D: φ × θ of the half vector), ``sigma`` (2-D: projected area over φi × θi), ``vndf`` and
``luminance`` (n_φ × n_θ × h × w), ``rgb`` (n_φ × n_θ × 3 × h × w), ``description`` (uint8 text),
``jacobian`` (uint8, 1 value). The material is isotropic when n_φ ≤ 2. (``spectra``/``wavelengths``
hold the spectral version; this reader uses ``rgb``.)

Evaluation (``BRDF::eval``): with wm = normalize(wi + wo), u(θ) = sqrt(θ / (π/2)),
u(φ) = (φ + π)/(2π):
``u_wi = (u(θi), u(φi))``, ``u_wm = (u(θm), u(φm − φi if isotropic else φm))`` (the φ part wrapped
to [0, 1)); ``s = vndf.invert(u_wm | φi, θi)`` (the inverse of the VNDF's marginal-conditional warp,
bilinear patches, parameters interpolated linearly); ``fr_c = max(0, rgb_c(s | φi, θi))``;
``eval = fr · ndf(u_wm) / (4 σ(u_wi))`` — that is f_r · cos θo. gonio's BRDF is ``eval / cos θo``,
with gonio's wi (toward the light) as powitacq's wi.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gonio.errors import DataError

__all__ = ["read_tensor_file", "read_bsdf", "PowitacqBRDF", "DTYPES"]

DTYPES = {1: "<u1", 2: "<i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4",
          11: "<f8"}
_MAX_FIELDS = 256
_MAX_BYTES = 2 ** 31


def read_tensor_file(path) -> dict[str, np.ndarray]:
    """The fields of a tensor file as arrays; :class:`DataError` naming the file and what is wrong."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror or exc})") from None

    def bad(what):
        return DataError(f"{path}: not a valid .bsdf tensor file: {what}")

    if len(raw) < 18 or raw[:12] != b"tensor_file\0":
        raise bad("no 'tensor_file' header")
    if raw[12:14] != b"\x01\x00":
        raise bad(f"version {raw[12]}.{raw[13]}, expected 1.0")
    n_fields = int.from_bytes(raw[14:18], "little")
    if n_fields > _MAX_FIELDS:
        raise bad(f"{n_fields} fields")
    pos, fields = 18, {}

    def take(n):
        nonlocal pos
        if pos + n > len(raw):
            raise bad("truncated field table")
        chunk = raw[pos:pos + n]
        pos += n
        return chunk

    for _ in range(n_fields):
        name_len = int.from_bytes(take(2), "little")
        try:
            name = take(name_len).decode("utf-8")
        except UnicodeDecodeError:
            raise bad("a field name is not UTF-8") from None
        ndim = int.from_bytes(take(2), "little")
        dtype = take(1)[0]
        offset = int.from_bytes(take(8), "little")
        if dtype not in DTYPES:
            raise bad(f"field {name!r} has unknown type {dtype}")
        shape = tuple(int.from_bytes(take(8), "little") for _ in range(ndim))
        count = int(np.prod(shape, dtype=object)) if shape else 1
        nbytes = count * np.dtype(DTYPES[dtype]).itemsize
        if nbytes > _MAX_BYTES or offset + nbytes > len(raw):
            raise bad(f"field {name!r} (shape {shape}) runs past the end of the file (truncated?)")
        fields[name] = np.frombuffer(raw, dtype=DTYPES[dtype], count=count, offset=offset).reshape(shape)
    return fields


def _check(path, f: dict) -> None:
    need = {"theta_i": (1, "<f4"), "phi_i": (1, "<f4"), "ndf": (2, "<f4"), "sigma": (2, "<f4"), "vndf": (4, "<f4"),
            "luminance": (4, "<f4"), "rgb": (5, "<f4"), "description": (1, "<u1"), "jacobian": (1, "<u1")}
    for name, (ndim, dt) in need.items():
        if name not in f:
            raise DataError(f"{path}: .bsdf file lacks field {name!r} (an RGB powitacq material needs "
                            f"{', '.join(need)})")
        if f[name].ndim != ndim or f[name].dtype != np.dtype(dt):
            raise DataError(f"{path}: .bsdf field {name!r} has shape {f[name].shape} and type {f[name].dtype}, "
                            f"expected {ndim} dimensions of {np.dtype(dt)}")
    n_phi, n_th = len(f["phi_i"]), len(f["theta_i"])
    v, lum, rgb = f["vndf"].shape, f["luminance"].shape, f["rgb"].shape
    ok = (v[:2] == (n_phi, n_th) and lum[:2] == (n_phi, n_th) and lum[2] == lum[3] and rgb[:3] == (n_phi, n_th, 3)
          and rgb[3:] == lum[2:] and f["jacobian"].shape == (1,) and min(v[2:] + f["ndf"].shape + f["sigma"].shape) >= 2
          and n_phi >= 1 and n_th >= 1 and rgb[3] >= 2 and rgb[4] >= 2)
    if not ok:
        raise DataError(f"{path}: .bsdf fields have inconsistent shapes (theta_i {n_th}, phi_i {n_phi}, vndf {v}, "
                        f"luminance {lum}, rgb {rgb})")
    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "rgb"):
        if not np.all(np.isfinite(f[name])):
            raise DataError(f"{path}: .bsdf field {name!r} holds NaN or inf")
    for name in ("theta_i", "phi_i"):
        if len(f[name]) > 1 and not np.all(np.diff(f[name]) > 0):
            raise DataError(f"{path}: .bsdf field {name!r} is not increasing")
    if n_phi > 2:
        reduction = int(np.rint(2 * np.pi / (float(f["phi_i"][-1]) - float(f["phi_i"][0]))))
        if reduction != 1:
            raise DataError(f"{path}: .bsdf phi_i covers 2π/{reduction}: symmetry reduction is not supported "
                            "(as in the reference implementation)")


def _params(values: np.ndarray, p: np.ndarray):
    """(index, w0, w1) of the linear interpolation of parameter ``p`` on ``values`` (``find_interval``:
    the interval clamped to [0, n − 2], weight clamped to [0, 1]); a single value: (0, 1, 0)."""
    n = len(values)
    if n == 1:
        z = np.zeros(np.shape(p), dtype=np.intp)
        return z, np.ones(np.shape(p)), np.zeros(np.shape(p))
    i = np.clip(np.searchsorted(values, p, side="right") - 1, 0, n - 2)
    p0, p1 = values[i], values[i + 1]
    w1 = np.clip((p - p0) / (p1 - p0), 0.0, 1.0)
    return i, 1.0 - w1, w1


def _bilinear(data: np.ndarray, pos_x, pos_y) -> np.ndarray:
    """``Marginal2D<0>::eval`` without normalization: bilinear interpolation of ``data`` (rows y,
    columns x) at ``pos`` in [0, 1]²."""
    ny, nx = data.shape
    x = pos_x * (nx - 1)
    y = pos_y * (ny - 1)
    ix = np.minimum(np.maximum(x, 0).astype(np.intp), nx - 2)
    iy = np.minimum(np.maximum(y, 0).astype(np.intp), ny - 2)
    wx, wy = x - ix, y - iy
    return ((1 - wy) * ((1 - wx) * data[iy, ix] + wx * data[iy, ix + 1])
            + wy * ((1 - wx) * data[iy + 1, ix] + wx * data[iy + 1, ix + 1]))


class _Warp:
    """``Marginal2D<2>`` with normalization and CDFs (the VNDF), for :meth:`invert`."""

    def __init__(self, data: np.ndarray):
        d = data.astype(np.float64)
        cond = np.zeros_like(d)
        cond[..., 1:] = np.cumsum(0.5 * (d[..., :-1] + d[..., 1:]), axis=-1)
        last = cond[..., -1]
        marg = np.zeros(d.shape[:-1])
        marg[..., 1:] = np.cumsum(0.5 * (last[..., :-1] + last[..., 1:]), axis=-1)
        norm = 1.0 / marg[..., -1]
        self.data = d * norm[..., None, None]
        self.cond = cond * norm[..., None, None]
        self.marg = marg * norm[..., None]
        self.ny, self.nx = d.shape[-2:]

    def invert(self, sx, sy, corners):
        """(sample x, sample y, pdf) of ``invert``; ``corners`` = [(phi index, theta index, weight)].

        Each table is read through flat indices (one per corner, offset by +1 / +nx for the neighbours): the same
        elements as indexing its four axes, without four index arrays per read."""
        nx, ny = self.nx, self.ny
        n_theta = self.data.shape[1]
        data, cond, marg = self.data.reshape(-1), self.cond.reshape(-1), self.marg.reshape(-1)

        sx = sx * (nx - 1)
        sy = sy * (ny - 1)
        px = np.minimum(np.maximum(sx, 0).astype(np.intp), nx - 2)
        py = np.minimum(np.maximum(sy, 0).astype(np.intp), ny - 2)
        sx = sx - px
        sy = sy - py
        rows = [((a * n_theta + b) * ny + py, w) for a, b, w in corners]  # flat (phi, theta, y) row per corner

        def lookup(arr, dy, x):  # Σ_corners w · arr[a, b, py + dy, x] (in the corners' order, from 0)
            total = 0
            for r, w in rows:
                total = total + w * arr.take((r + dy) * nx + x)
            return total

        v00, v10 = lookup(data, 0, px), lookup(data, 0, px + 1)
        v01, v11 = lookup(data, 1, px), lookup(data, 1, px + 1)
        c0 = (1 - sy) * v00 + sy * v01
        c1 = (1 - sy) * v10 + sy * v11
        pdf = (1 - sx) * c0 + sx * c1
        sx = sx * (c0 + 0.5 * sx * (c1 - c0))
        v0, v1 = lookup(cond, 0, px), lookup(cond, 1, px)
        sx = sx + (1 - sy) * v0 + sy * v1
        r0, r1 = lookup(cond, 0, nx - 1), lookup(cond, 1, nx - 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            sx = sx / ((1 - sy) * r0 + sy * r1)
        sy = sy * (r0 + 0.5 * sy * (r1 - r0))
        sy = sy + sum(w * marg.take(r) for r, w in rows)
        return sx, sy, pdf * (nx - 1) * (ny - 1)


@dataclass(frozen=True, eq=False)
class PowitacqBRDF:
    """An RGL material: ``eval(wi, wo)`` → BRDF (1/sr, RGB) by the reference procedure (module docstring)."""

    path: Path
    fields: dict

    @property
    def isotropic(self) -> bool:
        return len(self.fields["phi_i"]) <= 2

    @property
    def description(self) -> str:
        return bytes(self.fields["description"]).decode("utf-8", "replace").rstrip("\0")

    def __repr__(self) -> str:
        kind = "isotropic" if self.isotropic else "anisotropic"
        return f"PowitacqBRDF({self.path.name}, {kind}, {self.description[:40]!r})"

    def _warp(self) -> _Warp:
        w = self.__dict__.get("_w")
        if w is None:
            w = _Warp(self.fields["vndf"])
            object.__setattr__(self, "_w", w)
        return w

    def eval_cos(self, wi, wo) -> np.ndarray:
        """powitacq's ``BRDF::eval``: f_r · cos θo (RGB), 0 below the horizon."""
        f = self.fields
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        wi, wo = np.broadcast_arrays(wi, wo)
        above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        wm = wi + wo
        wm = wm / np.maximum(np.linalg.norm(wm, axis=-1, keepdims=True), 1e-300)
        th_i = np.arccos(np.clip(wi[..., 2], -1, 1))
        ph_i = np.arctan2(wi[..., 1], wi[..., 0])
        th_m = np.arccos(np.clip(wm[..., 2], -1, 1))
        ph_m = np.arctan2(wm[..., 1], wm[..., 0])
        u_wi = (np.sqrt(th_i * (2 / np.pi)), (ph_i + np.pi) / (2 * np.pi))
        uy = ((ph_m - ph_i if self.isotropic else ph_m) + np.pi) / (2 * np.pi)
        u_wm = (np.sqrt(th_m * (2 / np.pi)), uy - np.floor(uy))
        ip, p0, p1 = _params(f["phi_i"].astype(np.float64), ph_i)
        it, t0, t1 = _params(f["theta_i"].astype(np.float64), th_i)
        stride_p = 1 if len(f["phi_i"]) > 1 else 0
        stride_t = 1 if len(f["theta_i"]) > 1 else 0
        corners = [(ip, it, p0 * t0), (ip, it + stride_t, p0 * t1), (ip + stride_p, it, p1 * t0),
                   (ip + stride_p, it + stride_t, p1 * t1)]
        sx, sy, _ = self._warp().invert(u_wm[0], u_wm[1], corners)
        rgb = f["rgb"].astype(np.float64)
        ny, nx = rgb.shape[-2:]
        x = sx * (nx - 1)
        y = sy * (ny - 1)
        ix = np.minimum(np.maximum(np.nan_to_num(x), 0).astype(np.intp), nx - 2)
        iy = np.minimum(np.maximum(np.nan_to_num(y), 0).astype(np.intp), ny - 2)
        wx, wy = x - ix, y - iy
        out = np.zeros(wi.shape[:-1] + (3,))
        flat = rgb.reshape(-1)  # rgb[a, b, c, y, x] at ((a·nθ + b)·3 + c)·ny·nx + y·nx + x: read through flat indices
        cell = [((a * rgb.shape[1] + b) * 3 * ny + iy) * nx + ix for a, b, _ in corners]
        for c in range(3):
            val = 0.0
            for k, (_, _, w) in enumerate(corners):
                i = cell[k] + c * ny * nx
                val = val + w * ((1 - wy) * ((1 - wx) * flat.take(i) + wx * flat.take(i + 1))
                                 + wy * ((1 - wx) * flat.take(i + nx) + wx * flat.take(i + nx + 1)))
            out[..., c] = np.maximum(0.0, val)
        ndf = _bilinear(f["ndf"].astype(np.float64), u_wm[0], u_wm[1])
        sigma = _bilinear(f["sigma"].astype(np.float64), u_wi[0], u_wi[1])
        with np.errstate(invalid="ignore", divide="ignore"):
            out = out * (ndf / (4 * sigma))[..., None]
        return np.where(above[..., None], np.nan_to_num(out, nan=0.0, posinf=0.0), 0.0)

    def eval(self, wi, wo) -> np.ndarray:
        """BRDF (1/sr, RGB, not × cos): :meth:`eval_cos` / cos θo; 0 below the horizon."""
        wo = np.asarray(wo, dtype=np.float64)
        v = self.eval_cos(wi, wo)
        cos_o = wo[..., 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((cos_o > 0)[..., None], v / np.where(cos_o > 0, cos_o, 1.0)[..., None], 0.0)

    def to_samples(self, step_deg: float = 2.5):
        """Samples to fit or plot: incidences every 5° to 80° and the file's own θi grid below 85° (φi = 0,
        and for anisotropic materials every 30°) against outgoing directions every ``step_deg`` in θo (to 85°) and φo;
        σ = NaN (a fit then uses an unweighted loss)."""
        from gonio.geometry import from_spherical
        from gonio.samples import SampleSet

        th_i = self.fields["theta_i"].astype(np.float64)
        th_i = np.union1d(th_i[th_i < np.radians(85)], np.radians(np.arange(0.0, 81.0, 5.0)))
        ph_i = np.array([0.0]) if self.isotropic else np.radians(np.arange(0, 360, 30.0))
        th_o = np.radians(np.arange(step_deg / 2, 85, step_deg))
        ph_o = np.radians(np.arange(0, 360, step_deg))
        A, B, C, D = np.meshgrid(th_i, ph_i, th_o, ph_o, indexing="ij")
        wi = from_spherical(A.ravel(), B.ravel())
        wo = from_spherical(C.ravel(), D.ravel())
        f = self.eval(wi, wo)
        return SampleSet(wi, wo, f, np.full_like(f, np.nan))

    def to_table(self):
        """The material on the MERL grid (cell centres, φh = 0); isotropic materials only."""
        from gonio.io.merl import MerlTable

        if not self.isotropic:
            raise DataError(f"{self.path}: anisotropic material: a MERL table holds isotropic BRDFs only "
                            "(evaluate it with eval(), or fit its samples)")
        return MerlTable.from_brdf(self)


def read_bsdf(path) -> PowitacqBRDF:
    """Read and validate an RGL ``.bsdf`` material (module docstring)."""
    path = Path(path)
    fields = read_tensor_file(path)
    _check(path, fields)
    return PowitacqBRDF(path, fields)
