"""``python -m gonio.prior.build_default [--realdata DIR] [-o PRIOR.npz]``: build the prior shipped in the package
(``gonio/prior/data/default-prior.npz``) from the 63 real materials of ``../shared/realdata``.

Provenance (docs/prior.md): 12 materials of the MERL BRDF database (Matusik, Pfister, Brand & McMillan, "A
Data-Driven Reflectance Model", SIGGRAPH 2003) and 51 isotropic materials of the RGL-EPFL database (Dupuy &
Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and Rendering", SIGGRAPH Asia 2018),
each as the neural fit Sztrajman, Rainer, Ritschel & Weyrich trained on the real measurements ("Neural BRDF
Representation and Importance Sampling", CGF 40(6), 2021; weights MIT-licensed, github asztr/Neural-BRDF).
The networks are evaluated directly at the prior's grid nodes with the folder's own ``nbrdf_to_merl.evaluate``
(the same values its MERL tables hold at those angles, without writing 35 MB per material); only the prior —
principal components, not the weights or any table — ships.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["find_realdata", "realdata_materials", "node_values_realdata", "main"]


def find_realdata(given: str | None = None) -> Path | None:
    """The realdata folder: ``given``, ``$GONIO_REALDATA``, or ``../shared/realdata`` from the working directory
    or the repository; None when absent."""
    here = Path(__file__).resolve().parents[2]
    env = os.environ.get("GONIO_REALDATA")
    for p in [Path(x) for x in (given, env) if x] + [Path.cwd().parent / "shared/realdata",
                                                    here.parent / "shared/realdata", here.parent.parent / "shared/realdata"]:
        if (p / "nbrdf_to_merl.py").is_file():
            return p
    return None


def realdata_materials(folder: Path) -> tuple[object, dict]:
    """``(module, {name: network})`` of every material of the folder (MERL subset and RGL)."""
    spec = importlib.util.spec_from_file_location("gonio_realdata_nbrdf", folder / "nbrdf_to_merl.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    nets = dict(mod.load(str(folder / "merl_nbrdf_subset.npz")))
    nets.update(mod.load(str(folder / "rgl_nbrdf.npz")))
    return mod, nets


def node_values_realdata(mod, nets: dict, grid) -> tuple[list[str], np.ndarray]:
    """Names and node values (M, G, 3) of the networks at the grid's nodes."""
    th, td, pd = grid.node_angles()
    names = sorted(nets)
    return names, np.stack([mod.evaluate(nets[n], th, td, pd) for n in names])


def main(argv=None) -> int:
    from gonio.prior import DEFAULT_GRID, build_prior, save_prior
    from gonio.prior.model import default_prior_path

    ap = argparse.ArgumentParser(prog="python -m gonio.prior.build_default", description=__doc__.splitlines()[0])
    ap.add_argument("--realdata", default=None, metavar="DIR")
    ap.add_argument("-o", "--out", default=str(default_prior_path()), metavar="PRIOR.npz")
    a = ap.parse_args(argv)
    folder = find_realdata(a.realdata)
    if folder is None:
        print("build_default: ../shared/realdata not found (give --realdata DIR or set GONIO_REALDATA)", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    mod, nets = realdata_materials(folder)
    names, values = node_values_realdata(mod, nets, DEFAULT_GRID)
    prov = ("MERL (Matusik et al. 2003; 12 materials) and RGL-EPFL (Dupuy & Jakob 2018; 51 isotropic materials) as "
            "Sztrajman et al. 2021's neural fits (MIT-licensed weights, asztr/Neural-BRDF)")
    prior = build_prior(values, names, DEFAULT_GRID, metadata={"name": "default", "provenance": prov})
    out = save_prior(prior, a.out)
    print(prior.describe())
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB) in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
