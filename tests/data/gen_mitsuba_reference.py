"""Generate tests/data/mitsuba_roughconductor.json: reference values of Mitsuba 3's ``roughconductor``.

NOT run in CI, and mitsuba is NOT a dependency of gonio. To regenerate:

    pip install --target /tmp/mitsuba_env mitsuba
    PYTHONPATH=/tmp/mitsuba_env python tests/data/gen_mitsuba_reference.py

Uses the ``scalar_rgb`` variant, ``material = "none"`` (F = 1), specular_reflectance 1, GGX and
Beckmann (Mitsuba's Beckmann uses the rational Smith G1 approximation, Walter et al. 2007 eq. 27),
several alphas and direction pairs. Mitsuba's ``eval(ctx, si, wo)`` returns f · cos θ of the
direction passed to ``eval`` (here gonio's wi, the light), so the stored value is that divided by
wi_z: the BRDF f itself, comparable to ``gonio.brdf.make("microfacet", kd=0, ks=1, f0=1, ...)``.
In Mitsuba's terms ``si.wi`` is the camera direction (gonio's wo).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import mitsuba as mi

mi.set_variant("scalar_rgb")


def sph(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return [math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]


PAIRS = [  # (theta_i, phi_i, theta_o, phi_o) in degrees
    (0, 0, 0, 0), (30, 0, 30, 180), (30, 0, 35, 180), (30, 0, 45, 170), (45, 20, 10, 250),
    (60, 0, 60, 180), (60, 0, 50, 150), (75, 0, 75, 180), (80, 30, 70, 200), (20, 0, 70, 90),
    (85, 0, 85, 180), (10, 45, 60, 0), (50, 0, 20, 180), (40, 100, 40, 280), (89, 0, 89, 180),
]
ALPHAS = [0.05, 0.1, 0.2, 0.35, 0.5, 0.8, 1.0]


def main() -> None:
    rows = []
    for dist in ("ggx", "beckmann"):
        for alpha in ALPHAS:
            bsdf = mi.load_dict({"type": "roughconductor", "material": "none", "distribution": dist,
                                 "alpha": alpha, "sample_visible": False})
            for ti, pi, to, po in PAIRS:
                wi = sph(ti, pi)  # gonio: toward the light
                wo = sph(to, po)  # gonio: toward the camera
                si = mi.SurfaceInteraction3f()
                si.wi = mi.Vector3f(wo)
                si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
                val = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wi))
                f = float(val[0]) / wi[2]
                if f < 1e-12:
                    continue  # Mitsuba cuts D·cos < 1e-20 to 0; compare only where it is defined
                rows.append({"distribution": dist, "alpha": alpha, "wi": wi, "wo": wo, "f": f})
    fresnel = []  # mi.fresnel (dielectric, eta = n_t/n_i) and mi.fresnel_conductor (eta + i k)
    for cos in (1.0, 0.9, 0.7, 0.5, 0.3, 0.1, 0.02):
        for eta in (1.5, 1.33, 0.67):
            fresnel.append({"kind": "dielectric", "cos": cos, "eta": eta, "F": float(mi.fresnel(cos, eta)[0])})
        for eta, k in ((0.2, 3.0), (1.1, 2.5), (0.0, 1.0), (2.9, 3.1)):
            c = mi.fresnel_conductor(cos, mi.Complex2f(eta, k))
            fresnel.append({"kind": "conductor", "cos": cos, "eta": eta, "k": k, "F": float(c)})
    out = {
        "source": f"Mitsuba {mi.__version__} scalar_rgb roughconductor, material=none, divided by wi_z",
        "generator": "tests/data/gen_mitsuba_reference.py",
        "rows": rows,
        "fresnel": fresnel,
    }
    path = Path(__file__).with_name("mitsuba_roughconductor.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {len(rows)} values to {path}")


if __name__ == "__main__":
    main()
