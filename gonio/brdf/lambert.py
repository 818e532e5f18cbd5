"""Lambertian (ideal diffuse) reflection."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param


class Lambert(BRDF):
    """Ideal diffuse BRDF ``f = ρ / π``.

    The constant that makes a surface of albedo ρ reflect a fraction ρ of the incident flux
    (lecture notes ``004_6b0fa14dcb48ed2f.txt``, "The ideal diffuse BRDF is a constant ρ/π").

    Parameters
    ----------
    albedo : float or 3 floats
        Diffuse albedo ρ ∈ [0, 1] per RGB channel.
    """

    name = "lambert"
    PARAMS = {"albedo": Param("rgb", 0.0, 1.0, doc="diffuse albedo rho in [0, 1], per RGB channel")}

    def _lobes(self):
        return self.albedo / np.pi, []
