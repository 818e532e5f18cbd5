"""Renderer exports (issue 32): the cosine-weighted relative RMS error each renderer's own BRDF has against the
model it was exported from (the error ``--approx`` prints), for plastics, a clear-coated paint, a metal and a
diffuse material. pbrt-v4: the mix of diffuse and conductor materials (the baseline, same run) against
``coateddiffuse`` fitted by pbrt-v4's layered walk's expectation (gonio.io.pbrt_coated); glTF: the
specification's Appendix B BRDF (height-correlated Smith visibility); Mitsuba 3: its closest plugin.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.common import Table

MATERIALS = {
    "red plastic (default)": {"kd": [0.3, 0.12, 0.06], "ks": 0.8, "alpha": 0.25, "f0": 0.04},
    "white glossy plastic": {"kd": [0.7, 0.7, 0.7], "ks": 1.0, "alpha": 0.08, "f0": 0.04},
    "rough green plastic": {"kd": [0.1, 0.3, 0.1], "ks": 0.5, "alpha": 0.5, "f0": 0.04},
    "clear-coated dark paint": {"kd": [0.05, 0.05, 0.12], "ks": 1.0, "alpha": 0.05, "f0": 0.05},
    "rough gold": {"kd": [0.0, 0.0, 0.0], "ks": 1.0, "alpha": 0.3, "f0": [1.0, 0.78, 0.34]},
    "diffuse": {"kd": [0.5, 0.35, 0.25], "ks": 0.0, "alpha": 0.3, "f0": 0.04},
}


def run(quick: bool = False) -> list[Table]:
    from gonio.brdf import make
    from gonio.io.approx import direction_pairs, relative_error
    from gonio.io.gltf import to_gltf
    from gonio.io.mitsuba import mitsuba_export
    from gonio.io.pbrt import pbrt_eval, pbrt_terms, to_pbrt

    names = list(MATERIALS)[:2] if quick else list(MATERIALS)
    t = Table("Renderer exports: cosine-weighted relative RMS error of the renderer's own BRDF (%)",
              ["material", "pbrt mix", "pbrt written", "pbrt material", "ratio to mix", "pbrt export s", "glTF",
               "Mitsuba 3"])
    wi, wo = direction_pairs()
    for name in names:
        model = make("microfacet", distribution="ggx", **MATERIALS[name])
        want = model.eval(wi, wo)
        mix = relative_error(pbrt_eval(pbrt_terms(model, True)[0], wi, wo), want)
        t0 = time.perf_counter()
        ex = to_pbrt(model, approx=True)
        seconds = time.perf_counter() - t0
        kind = "coateddiffuse" if '"coateddiffuse"' in ex.text else "diffuse/conductor mix"
        ratio = ex.error / mix if mix > 0 else float("nan")
        t.add(name, 100 * mix, 100 * ex.error, kind, ratio, seconds, 100 * to_gltf(model, approx=True).error,
              100 * mitsuba_export(model, approx=True).error)
    t.notes += ["pbrt mix: the diffuse + conductor mix gonio wrote before coateddiffuse (the baseline of the ratio); "
                "pbrt written: what --pbrt --approx writes now (the closer of the two)",
                "errors over 8192 cosine-distributed direction pairs (gonio.io.approx.direction_pairs); the "
                "coateddiffuse expectation agrees with a port of pbrt-v4's walk within its Monte Carlo noise "
                "(tests/io/test_pbrt_coateddiffuse.py)"]
    if not np.isfinite([r[4] for r in t.rows if isinstance(r[4], float)]).all():
        t.notes.append("a ratio is undefined where the mix is exact")
    return [t]
