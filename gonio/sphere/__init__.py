"""Image-based acquisition on curved samples (issue 30): a sphere's geometry as a camera sees it
(:mod:`gonio.sphere.geometry`), one BRDF sample per pixel from a merged frame (:mod:`gonio.sphere.pixels`), and
streaming binning into MERL cells (:mod:`gonio.cells`)."""

from gonio.cells import CellAccumulator
from gonio.sphere.geometry import Sphere, SphereHits, ray_sphere, sphere_hits
from gonio.sphere.pixels import SphereFrameSamples, sphere_frame_samples, white_scale

__all__ = ["Sphere", "SphereHits", "ray_sphere", "sphere_hits", "CellAccumulator", "SphereFrameSamples",
           "sphere_frame_samples", "white_scale"]
