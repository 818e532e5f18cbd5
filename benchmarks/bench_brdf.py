"""BRDF evaluation speed (float64 vs float32, with float32's error) and Schlick's rational
approximation t/(s − s t + t) against the exact power t^s: speed ratio and error over the lobe.

Baselines measured in the same run: Lambert (the cheapest model: the cost of the eval wrapper
itself) for the model table; exact ``np.power`` for the Schlick table.
"""

from __future__ import annotations

import numpy as np

from benchmarks.common import Table, time_call
from gonio.brdf import make
from gonio.brdf.fresnel import schlick_rational_power
from gonio.geometry import from_spherical

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


def run(quick: bool = False) -> list[Table]:
    n = 50_000 if quick else 1_000_000
    min_time = 0.05 if quick else 0.3
    wi, wo = _directions(n)
    wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)

    t = Table(f"BRDF evaluations per second ({n:,} direction pairs per call, one core)",
              ["model", "float64 Meval/s", "cost vs lambert", "float32 Meval/s", "f32 speed-up",
               "f32 max rel err", "f32 p99 rel err"], baseline=0, default=None)
    for name, params in MODELS:
        m = make(name, **params)
        label = name + (f" ({params['distribution']})" if "distribution" in params else "")
        s64 = time_call(lambda: m.eval(wi, wo), min_time=min_time)
        s32 = time_call(lambda: m.eval(wi32, wo32, dtype=np.float32), min_time=min_time)
        f64 = m.eval(wi32.astype(np.float64), wo32.astype(np.float64))
        f32 = m.eval(wi32, wo32, dtype=np.float32).astype(np.float64)
        big = f64 > 1e-6 * f64.max()  # relative error where the value is not negligible
        rel = np.abs(f32[big] - f64[big]) / f64[big]
        if not t.rows:
            base = s64
        t.add(label, n / s64 / 1e6, s64 / base, n / s32 / 1e6, s64 / s32, float(rel.max()),
              float(np.quantile(rel, 0.99)))
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
