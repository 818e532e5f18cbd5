"""BRDF evaluation speed: the microfacet models on gonio's NumPy and compiled (numba) paths against a
plain NumPy GGX and the memory-bandwidth ceiling; every model in float64 vs float32 (with float32's
error); and Schlick's rational approximation t/(s − s t + t) against the exact power t^s.

Baselines measured in the same run: a straightforward NumPy GGX written here (what a user would write)
and a streaming pass over the same arrays (the memory ceiling) for the evaluation table; Lambert (the
cost of the eval wrapper itself) for the model table; exact ``np.power`` for the Schlick table.
One thread (OMP/OPENBLAS/NUMBA threads = 1; NumPy's element-wise work and the compiled loop are
single-threaded anyway); CPU time of this process, medians.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from benchmarks.common import Table, round_time, time_call, time_median, timed_calls  # noqa: E402
from gonio.brdf import compiled, make  # noqa: E402
from gonio.brdf.fresnel import schlick_rational_power  # noqa: E402
from gonio.geometry import from_spherical  # noqa: E402

#: The microfacet models, the other models with a compiled form, and a two-lobe sum (the evaluation table).
MICROFACET = [
    ("ggx", "microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.2, "f0": 0.04, "distribution": "ggx"}),
    ("beckmann", "microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.2, "f0": 0.04, "distribution": "beckmann"}),
    ("cook-torrance", "cook-torrance", {"kd": 0.2, "ks": 0.5, "roughness": 0.2, "f0": 0.04}),
    ("gtr (γ = 1.5)", "gtr", {"kd": 0.2, "ks": 0.5, "alpha": 0.2, "gamma": 1.5, "f0": 0.04}),
    ("abc", "abc", {"kd": 0.1, "A": 2.0, "B": 1000.0, "C": 0.8, "eta": 1.5}),
    ("ashikhmin-shirley", "ashikhmin-shirley", {"rd": 0.5, "rs": 0.05, "nu": 100, "nv": 20}),
    ("abc-smooth", "abc-smooth", {"kd": 0.1, "A": 2.0, "B": 1000.0, "C": 0.8, "eta": 1.5}),
    ("lambert+2ggx", "lambert+2ggx", {"diffuse.albedo": 0.2, "lobe1.ks": 0.3, "lobe1.alpha": 0.05, "lobe1.f0": 0.04,
                                      "lobe2.ks": 0.2, "lobe2.alpha": 0.4, "lobe2.f0": 0.04}),
]


def plain_numpy_ggx(wi, wo, kd, ks, alpha, f0):
    """GGX microfacet + Lambert written the straightforward NumPy way (the benchmark's baseline, not gonio's
    code): f = kd/π + ks D G2 F / (4 cos θi cos θo), D = α²/(π ((α² − 1) cos²θh + 1)²),
    G1 = 2 cos θ / (cos θ + √(α² + (1 − α²) cos²θ)), F = f0 + (1 − f0)(1 − wo·h)⁵ (Walter et al. 2007, eqs.
    20, 33, 34; Schlick 1994). No guards: the benchmark's directions are above the horizon."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ci, co, ch = wi[:, 2], wo[:, 2], h[:, 2]
    a2 = alpha * alpha
    d = a2 / (np.pi * ((a2 - 1.0) * ch * ch + 1.0) ** 2)

    def g1(c):
        return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))

    f = f0 + (1.0 - f0) * (1.0 - np.sum(wo * h, axis=-1)) ** 5
    return kd / np.pi + ks * (d * g1(ci) * g1(co) * f / (4.0 * ci * co))[:, None]


def _evaluation_table(wi, wo, repeat: int) -> Table:
    n = len(wi)
    out = np.empty_like(wi)
    t_ceiling = time_median(lambda: np.add(wi, wo, out=out), repeat=repeat)
    t_plain = time_median(lambda: plain_numpy_ggx(wi, wo, 0.2, 0.5, 0.2, 0.04), repeat=repeat)
    t = Table(f"BRDF evaluation, float64, {n:,} direction pairs, one thread (CPU time, median of {repeat})",
              ["model", "path", "Meval/s", "× plain NumPy GGX", "ceiling / this", "vs one lobe (same path)"],
              baseline=1, default=None)
    t.add("memory ceiling", "np.add(wi, wo, out): reads wi, wo, writes (n, 3)", n / t_ceiling / 1e6,
          t_plain / t_ceiling, 1.0, "")
    t.add("ggx", "plain NumPy (written in the benchmark)", n / t_plain / 1e6, 1.0, t_plain / t_ceiling, "")
    one_lobe = {}
    fast = compiled.available()
    for label, name, params in MICROFACET:
        model = make(name, **params)
        paths = [("numpy", "gonio NumPy path")]
        if fast and compiled.supports(model):
            paths.append(("compiled", "gonio compiled path (numba)"))
        for backend, desc in paths:
            sec = time_median(lambda: model.eval(wi, wo, backend=backend), repeat=repeat)
            one_lobe.setdefault(backend, sec)
            vs = f"{sec / one_lobe[backend]:.2f}× ggx" if label == "lambert+2ggx" else ""
            t.add(label, desc, n / sec / 1e6, t_plain / sec, sec / t_ceiling, vs)
        if not fast:
            t.add(label, "gonio compiled path: numba not installed (pip install 'gonio[fast]')", 0.0, 0.0, 0.0, "")
    ref = make("microfacet", **MICROFACET[0][2]).eval(wi, wo, backend="numpy")
    plain = plain_numpy_ggx(wi, wo, 0.2, 0.5, 0.2, 0.04)
    t.notes.append("Targets (issue 17): ≥ 40 Meval/s for every microfacet model, ≥ 2.5× the plain NumPy GGX, "
                   "ceiling / this ≤ 12, a two-lobe sum ≤ 1.3× one lobe. × plain NumPy GGX > 1 = faster.")
    from gonio.brdf import MODELS

    without = sorted(n for n, cls in MODELS.items() if "+" not in n and not compiled.supports(
        cls(**{k: p.lo for k, p in cls.PARAMS.items() if p.default is None})))
    t.notes.append(f"Models without a compiled form (NumPy only): {', '.join(without)} — not written as lobes on the "
                   "shared pair geometry (gonio.brdf.pairs) yet; none of them is a microfacet model.")
    t.notes.append(f"plain NumPy GGX vs gonio: max relative difference {float(np.max(np.abs(plain - ref) / ref)):.1e} "
                   "(its 1 − wo·h cancels near normal incidence; gonio's compiled and NumPy paths agree to ≤ 1e-12, "
                   "tests/brdf/test_compiled.py).")
    return t


def run(quick: bool = False) -> list[Table]:
    n = 50_000 if quick else 1_000_000
    wi, wo = _directions(n)
    return [_evaluation_table(wi, wo, timed_calls(quick)), *_models_and_schlick(wi, wo, quick)]

MODELS = [
    ("lambert", {"albedo": 0.5}),
    ("phong", {"kd": 0.2, "ks": 0.5, "exponent": 50}),
    ("blinn-phong", {"kd": 0.2, "ks": 0.5, "exponent": 50}),
    ("cook-torrance", {"kd": 0.2, "ks": 0.5, "roughness": 0.2, "f0": 0.04}),
    ("microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.2, "distribution": "ggx"}),
    ("microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.2, "distribution": "beckmann"}),
    ("ward", {"kd": 0.2, "ks": 0.5, "alpha_x": 0.1, "alpha_y": 0.3}),
    ("lafortune", {"kd": 0.2, "lobes": [(-1, 1, 30, 3.0), (-0.5, 0.8, 5, 0.5)]}),
    ("oren-nayar", {"albedo": 0.5, "sigma": 0.3}),
    ("ashikhmin-shirley", {"rd": 0.5, "rs": 0.05, "nu": 100, "nv": 20}),
    ("lambert+2ggx", {"diffuse.albedo": 0.3, "lobe1.ks": 0.3, "lobe1.alpha": 0.05, "lobe2.ks": 0.2, "lobe2.alpha": 0.4}),
]


def _directions(n: int):
    rng = np.random.default_rng(0)
    wi = from_spherical(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    return wi, wo


def _models_and_schlick(wi, wo, quick: bool) -> list[Table]:
    n = len(wi)
    min_time, reps = round_time(quick), timed_calls(quick, 3, 3)
    wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)

    t = Table(f"BRDF evaluations per second ({n:,} direction pairs per call, one core; float64 on the default path)",
              ["model", "float64 path", "float64 Meval/s", "cost vs lambert", "float32 Meval/s", "f32 speed-up",
               "f32 max rel err", "f32 p99 rel err"], baseline=0, default=None)
    for name, params in MODELS:
        m = make(name, **params)
        label = name + (f" ({params['distribution']})" if "distribution" in params else "")
        s64 = time_median(lambda: m.eval(wi, wo), repeat=reps)  # CPU time, as the evaluation table
        s32 = time_median(lambda: m.eval(wi32, wo32, dtype=np.float32), repeat=reps)
        f64 = m.eval(wi32.astype(np.float64), wo32.astype(np.float64))
        f32 = m.eval(wi32, wo32, dtype=np.float32).astype(np.float64)
        big = f64 > 1e-6 * f64.max()  # relative error where the value is not negligible
        rel = np.abs(f32[big] - f64[big]) / f64[big]
        if not t.rows:
            base = s64
        path = "compiled" if compiled.wanted(m, wi, np.dtype(np.float64), "auto") else "numpy"
        t.add(label, path, n / s64 / 1e6, s64 / base, n / s32 / 1e6, s64 / s32, float(rel.max()),
              float(np.quantile(rel, 0.99)))
    t.notes.append(f"CPU time, median of {reps} call{'s' * (reps > 1)}. float64 runs on the compiled path where the "
                   "model has one and numba is installed (float32 is NumPy only), so the f32 speed-up is < 1 there.")
    t.notes.append("float32 error: relative to float64 evaluation of the same (float32) directions, over "
                   "values above 1e-6 of the maximum: the error of float32 arithmetic alone.")

    # Schlick's rational approximation vs exact power, over a Blinn-Phong lobe (t = n·h in [0, 1]).
    ts = np.cos(np.linspace(0, np.pi / 2, n))
    s_tab = Table(f"t^s: exact power vs Schlick's t/(s − s t + t) ({n:,} values of t = cos θ_h over the lobe)",
                  ["s", "method", "Meval/s", "speed vs pow", "max abs err", "mean abs err (t^s > 1e-3)",
                   "max rel err (t^s > 1e-3)"], baseline=0, default=0,
                  why_default="gonio evaluates the exact power by default; Schlick's form is an option of "
                              "the lighting model (shade(schlick=True)).")
    for s in (10.0, 50.0, 500.0):
        exact = ts ** s
        lobe = exact > 1e-3
        p_s = time_call(lambda: np.power(ts, s), min_time=min_time)
        r_s = time_call(lambda: schlick_rational_power(ts, s), min_time=min_time)
        raw = time_call(lambda: ts / (s - s * ts + ts), min_time=min_time)
        approx = schlick_rational_power(ts, s)
        err = np.abs(approx - exact)
        if not s_tab.rows:
            p0 = p_s
        s_tab.add(s, "np.power (exact)", n / p_s / 1e6, p0 / p_s, 0.0, 0.0, 0.0)
        s_tab.add(s, "Schlick rational (guarded)", n / r_s / 1e6, p_s / r_s, float(err.max()),
                  float(err[lobe].mean()), float((err[lobe] / exact[lobe]).max()))
        s_tab.add(s, "Schlick rational (bare t/(s-st+t))", n / raw / 1e6, p_s / raw, float(err.max()),
                  float(err[lobe].mean()), float((err[lobe] / exact[lobe]).max()))
    s_tab.notes.append("speed vs pow: ratio to np.power at the same s (> 1 = faster); errors are of the "
                       "approximation, identical for the guarded and bare forms.")
    return [t, s_tab]
