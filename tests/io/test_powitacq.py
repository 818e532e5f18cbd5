"""RGL ``.bsdf`` (Dupuy & Jakob 2018, powitacq tensor files): files written here in that format, read by
gonio.load, evaluated against an independent scalar port of powitacq_rgb's BRDF::eval (written in this
file from the reference, float64) and against a known constant lobe; looked up, tabulated and fitted."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

import gonio
from gonio.errors import DataError
from gonio.geometry import from_spherical

CODES = {np.dtype("<f4"): 10, np.dtype("<u1"): 1, np.dtype("<f8"): 11}


def write_tensor_file(path, fields: dict) -> None:
    """The tensor file layout: header, field table (name, ndim, dtype, offset, shape), then the data."""
    table = b""
    entries = [(name, np.ascontiguousarray(a)) for name, a in fields.items()]
    header_size = 12 + 2 + 4 + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim for n, a in entries)
    offset, blobs = header_size, []
    for name, a in entries:
        nb = name.encode()
        table += struct.pack("<H", len(nb)) + nb + struct.pack("<HBQ", a.ndim, CODES[a.dtype], offset)
        table += b"".join(struct.pack("<Q", s) for s in a.shape)
        blobs.append(a.tobytes())
        offset += a.nbytes
    with open(path, "wb") as fh:
        fh.write(b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", len(entries)) + table + b"".join(blobs))


def material(rng, n_phi=1, n_theta=4, res=6, constant=None):
    f32 = np.float32
    theta = np.linspace(0, np.pi / 2 * 0.95, n_theta).astype(f32)
    phi = (np.array([0.0]) if n_phi == 1 else np.linspace(-np.pi, np.pi, n_phi)).astype(f32)
    if constant is None:
        vndf = rng.uniform(0.2, 2.0, (n_phi, n_theta, res, res))
        rgb = rng.uniform(0.0, 1.0, (n_phi, n_theta, 3, res, res))
        rgb[0, 0, 0, 0, 0] = -0.1  # out of gamut: clipped to 0 by eval
        ndf = rng.uniform(0.5, 3.0, (res, res + 1))
        sigma = rng.uniform(0.5, 1.5, (res + 2, res))
    else:
        k, n, s = constant
        vndf = np.ones((n_phi, n_theta, res, res))
        rgb = np.broadcast_to(np.array(k)[:, None, None], (n_phi, n_theta, 3, res, res)).copy()
        ndf = np.full((res, res), n)
        sigma = np.full((res, res), s)
    return {"theta_i": theta, "phi_i": phi, "ndf": ndf.astype(f32), "sigma": sigma.astype(f32),
            "vndf": vndf.astype(f32), "luminance": vndf.astype(f32), "rgb": rgb.astype(f32),
            "description": np.frombuffer(b"test material", np.uint8), "jacobian": np.array([1], np.uint8)}


# --- an independent scalar port of powitacq_rgb.inl (BRDF::eval, Marginal2D::invert/eval) ----------------
def find_interval(size, pred):
    size_, first = size - 2, 1
    while size_ > 0:
        half = size_ >> 1
        middle = first + half
        if pred(middle):
            first, size_ = middle + 1, size_ - (half + 1)
        else:
            size_ = half
    return min(max(first - 1, 0), size - 2)


class Marginal2D:
    def __init__(self, data, param_values, normalize, build_cdf):
        self.param_values = [np.asarray(v, dtype=np.float64) for v in param_values]
        self.size_y, self.size_x = data.shape[-2:]
        res = [len(v) for v in self.param_values]
        self.strides, slices = [0] * len(res), 1
        for i in range(len(res) - 1, -1, -1):
            self.strides[i] = slices if res[i] > 1 else 0
            slices *= res[i]
        d = np.asarray(data, dtype=np.float64).reshape(slices, self.size_y, self.size_x)
        self.data, self.cond, self.marg = [], [], []
        for sl in d:
            if build_cdf:
                cond = np.zeros_like(sl)
                for y in range(self.size_y):
                    s = 0.0
                    for x in range(self.size_x - 1):
                        s += 0.5 * (sl[y, x] + sl[y, x + 1])
                        cond[y, x + 1] = s
                marg = np.zeros(self.size_y)
                s = 0.0
                for y in range(self.size_y - 1):
                    s += 0.5 * (cond[y, -1] + cond[y + 1, -1])
                    marg[y + 1] = s
                norm = 1.0 / marg[-1]
                self.data.append(sl * norm)
                self.cond.append(cond * norm)
                self.marg.append(marg * norm)
            else:
                self.data.append(sl)  # normalize=False: scaled by 1/hprod then multiplied back in eval
        self.inv_patch = (self.size_x - 1, self.size_y - 1)

    def _weights(self, param):
        """[(slice index, weight)] over the parameter corners."""
        out = [(0, 1.0)]
        for dim, values in enumerate(self.param_values):
            if len(values) == 1:
                continue
            idx = find_interval(len(values), lambda i: values[i] <= param[dim])
            p0, p1 = values[idx], values[idx + 1]
            w1 = min(max((param[dim] - p0) / (p1 - p0), 0.0), 1.0)
            out = [(s + self.strides[dim] * idx, w * (1 - w1)) for s, w in out] + \
                  [(s + self.strides[dim] * (idx + 1), w * w1) for s, w in out]
        return out

    def _lookup(self, arrays, corners, *index):
        return sum(w * arrays[s][index] for s, w in corners)

    def eval(self, pos, param):
        corners = self._weights(param)
        x, y = pos[0] * self.inv_patch[0], pos[1] * self.inv_patch[1]
        ox, oy = min(int(x), self.size_x - 2), min(int(y), self.size_y - 2)
        w1x, w1y = x - ox, y - oy
        v00 = self._lookup(self.data, corners, oy, ox)
        v10 = self._lookup(self.data, corners, oy, ox + 1)
        v01 = self._lookup(self.data, corners, oy + 1, ox)
        v11 = self._lookup(self.data, corners, oy + 1, ox + 1)
        return (1 - w1y) * ((1 - w1x) * v00 + w1x * v10) + w1y * ((1 - w1x) * v01 + w1x * v11)

    def invert(self, sample, param):
        corners = self._weights(param)
        sx, sy = sample[0] * self.inv_patch[0], sample[1] * self.inv_patch[1]
        px, py = min(int(sx), self.size_x - 2), min(int(sy), self.size_y - 2)
        sx, sy = sx - px, sy - py
        L = lambda arr, *i: self._lookup(arr, corners, *i)  # noqa: E731
        v00, v10, v01, v11 = L(self.data, py, px), L(self.data, py, px + 1), L(self.data, py + 1, px), L(self.data, py + 1, px + 1)
        c0 = (1 - sy) * v00 + sy * v01
        c1 = (1 - sy) * v10 + sy * v11
        sx *= c0 + 0.5 * sx * (c1 - c0)
        sx += (1 - sy) * L(self.cond, py, px) + sy * L(self.cond, py + 1, px)
        r0, r1 = L(self.cond, py, self.size_x - 1), L(self.cond, py + 1, self.size_x - 1)
        sx /= (1 - sy) * r0 + sy * r1
        sy *= r0 + 0.5 * sy * (r1 - r0)
        sy += L(self.marg, py)
        return sx, sy


class ReferenceBRDF:
    def __init__(self, f):
        self.iso = len(f["phi_i"]) <= 2
        self.ndf = Marginal2D(f["ndf"], [], False, False)
        self.sigma = Marginal2D(f["sigma"], [], False, False)
        self.vndf = Marginal2D(f["vndf"], [f["phi_i"], f["theta_i"]], True, True)
        self.rgb = Marginal2D(f["rgb"], [f["phi_i"], f["theta_i"], [0.0, 1.0, 2.0]], False, False)

    def eval(self, wi, wo):
        if wi[2] <= 0 or wo[2] <= 0:
            return np.zeros(3)
        wm = (wi + wo) / math.sqrt((wi + wo) @ (wi + wo))
        theta_i, phi_i = math.acos(wi[2]), math.atan2(wi[1], wi[0])
        theta_m, phi_m = math.acos(wm[2]), math.atan2(wm[1], wm[0])
        u_wi = (math.sqrt(theta_i * (2 / math.pi)), (phi_i + math.pi) / (2 * math.pi))
        uy = ((phi_m - phi_i if self.iso else phi_m) + math.pi) / (2 * math.pi)
        u_wm = (math.sqrt(theta_m * (2 / math.pi)), uy - math.floor(uy))
        sample = self.vndf.invert(u_wm, (phi_i, theta_i))
        fr = np.array([max(0.0, self.rgb.eval(sample, (phi_i, theta_i, float(c)))) for c in range(3)])
        return fr * self.ndf.eval(u_wm, ()) / (4 * self.sigma.eval(u_wi, ()))


def directions(n, seed):
    rng = np.random.default_rng(seed)
    wi = from_spherical(np.arccos(rng.uniform(0.02, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(np.arccos(rng.uniform(0.02, 1, n)), rng.uniform(0, 2 * np.pi, n))
    return wi, wo


@pytest.mark.parametrize("n_phi", [1, 5], ids=["isotropic", "anisotropic"])
def test_eval_matches_the_reference_procedure(tmp_path, n_phi):
    rng = np.random.default_rng(n_phi)
    f = material(rng, n_phi=n_phi)
    path = tmp_path / "m.bsdf"
    write_tensor_file(path, f)
    data = gonio.load(path)
    assert data.kind == "bsdf" and data.brdf.isotropic == (n_phi == 1)
    assert data.metadata["description"] == "test material"
    ref = ReferenceBRDF({k: v for k, v in f.items()})
    wi, wo = directions(300, n_phi)
    expect = np.array([ref.eval(a, b) for a, b in zip(wi, wo)])
    got = data.brdf.eval_cos(wi, wo)
    np.testing.assert_allclose(got, expect, rtol=1e-9, atol=1e-12)
    # gonio's BRDF is eval / cos θo; below the horizon 0
    np.testing.assert_allclose(data.eval(wi, wo), expect / wo[:, 2:3], rtol=1e-9)
    assert (data.eval(wi, -wo) == 0).all()


def test_known_constant_lobe(tmp_path):
    k, n, s = [0.25, 0.5, 0.75], 3.0, 1.5  # float32-exact
    path = tmp_path / "c.bsdf"
    write_tensor_file(path, material(None, constant=(k, n, s)))
    data = gonio.load(path)
    wi, wo = directions(200, 3)
    # uniform VNDF: the warp is the identity, so eval = k · n / (4 s) everywhere above the horizon
    np.testing.assert_allclose(data.brdf.eval_cos(wi, wo), np.outer(np.ones(200), k) * n / (4 * s), rtol=1e-12)
    np.testing.assert_allclose(data.eval(wi, wo) * wo[:, 2:3], data.brdf.eval_cos(wi, wo), rtol=1e-12)


def test_lookup_plot_and_fit_an_rgl_material(tmp_path):
    k, n, s = [0.25, 0.5, 0.75], 3.0, 1.5  # float32-exact
    path = tmp_path / "c.bsdf"
    write_tensor_file(path, material(None, constant=(k, n, s)))
    data = gonio.load(path)
    table = data.tabulated()
    wi, wo = directions(50, 4)
    lut = table.lookup(wi, wo, method="nearest")
    assert np.isfinite(lut).all() and (lut > 0).all()
    samples = data.to_samples()
    assert len(samples) > 1000 and np.isnan(samples.sigma).all()
    res = gonio.fit(data, "lambert")
    assert all(0 < a < 2 for a in res.params["albedo"])
    from gonio.cli.main import main

    assert main(["fit", str(path), "--model", "lambert"]) == 0
    pytest.importorskip("matplotlib", reason="matplotlib is the optional 'plots' extra")
    for kind in ("polar", "inplane"):
        assert main(["plot", str(path), "--kind", kind, "--theta-i", "30", "-o", str(tmp_path / f"{kind}.png")]) == 0
        assert (tmp_path / f"{kind}.png").stat().st_size > 10_000


def test_bad_bsdf_files_are_one_line(tmp_path):
    rng = np.random.default_rng(0)
    f = material(rng)
    path = tmp_path / "m.bsdf"
    write_tensor_file(path, {k: v for k, v in f.items() if k != "rgb"})
    with pytest.raises(DataError, match=r"m.bsdf: .bsdf file lacks field 'rgb'"):
        gonio.load(path)
    write_tensor_file(path, f)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 100])
    with pytest.raises(DataError, match=r"runs past the end of the file \(truncated\?\)"):
        gonio.load(path)
    g = dict(f, vndf=f["vndf"][:, :2])
    write_tensor_file(path, g)
    with pytest.raises(DataError, match="inconsistent shapes"):
        gonio.load(path)
