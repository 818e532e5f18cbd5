"""One pose of a sphere, after its bracket is merged: the centre refined from the silhouette, then one BRDF sample
per pixel with the refined centre (issue 30: a sphere declared a millimetre off biases every pixel's normal).

The centre a pose's samples use is the declared one combined with the silhouettes of the poses stored before it and
its own (:func:`gonio.sphere.refine.centre_in_use`); that centre's uncertainty is carried into every sample's σ
(:func:`gonio.sphere.pixels.sphere_frame_samples`). The poses before it come from the session's records (the
runner reads them back on a resume), so a resumed session uses, pose by pose, the very centre an uninterrupted one
used: bit-identical samples.
"""

from __future__ import annotations

import numpy as np

from gonio.sphere.geometry import Sphere
from gonio.sphere.pixels import SphereFrameSamples, sphere_frame_samples
from gonio.sphere.refine import centre_in_use, refine_centre, session_centre

__all__ = ["sphere_pose_samples"]


def sphere_pose_samples(rate, var, calib, cam_pose, declared: Sphere, light_position, layout, *, history=(),
                        min_snr: float = 5.0, pose_perturbations=()) -> SphereFrameSamples:
    """The pose's samples (``rate``/``var`` (H, W, C), NaN where not measured); ``history``: the earlier poses'
    record metas (their ``sphere_centre``), in pose order. The counts get ``centre`` (this pose's silhouette
    estimate, when found) and ``centre_used`` (the centre and σ its samples used)."""
    history = list(history)
    prior = session_centre(history, declared)
    current, _ = centre_in_use(prior, declared)
    est = refine_centre(rate, calib, cam_pose, current)  # the edges searched around the best centre so far
    mine = None
    if est is not None:
        mine = {"centre_m": est.centre.tolist(), "sigma_m": est.sigma.tolist(), "edges": est.n_edges}
        history.append({"sphere_centre": mine})
    used, sigma = centre_in_use(session_centre(history, declared) if mine else prior, declared)
    fs = sphere_frame_samples(rate, var, calib, cam_pose, used, light_position, layout, min_snr=min_snr,
                              pose_perturbations=pose_perturbations, centre_sigma=sigma)
    if mine is not None:
        fs.counts["centre"] = mine
    fs.counts["centre_used"] = {"centre_m": list(used.centre), "sigma_m": np.asarray(sigma).tolist()}
    return fs
