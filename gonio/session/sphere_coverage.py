"""Which MERL cells a sphere plan fills, before anything moves: each pose's camera and light from the rig's
kinematics, the sphere's pixels traced (:func:`gonio.sphere.geometry.sphere_hits`), their (θh, θd, φd) cells
collected — geometry only, no rendering, so a plan is judged in a fraction of a second per pose.

*Valid* cells are the MERL cells whose centre directions (φh = 0) are both above the horizon. *Reachable* ones
(:func:`reachable_cells`) are those the rig can put a sample in with the camera where the plan keeps it: a valid cell
whose configuration the pipeline keeps (θi and θo in the normal's frame within the grazing limit, 80°) and whose θd
lies between the least and the largest θd any pixel sees at a light position the rig reaches (joint limits,
collision and shadow zones, the white reference in view). Nothing else constrains a cell: on a sphere every normal
facing the camera is seen, the local θi and θo do not depend on the world's orientation, and for any light at the
right angle to the camera some normal has the cell's (θh, φd). This is the limit that a sweep of ever finer light
steps approaches — a sampled sweep's cells are not: at 320×240 a sweep every 5°, 2.5° and 1.25° fills 229,452,
418,806 and 560,082 cells, the limit is ~890,000 (the sampled count grows with the sweep's density and the camera's
pixels, so coverage against it says more about the sweep than about the plan). Coverage is reported against the
valid and the reachable cells, and per θh and θd band.

The closed form is checked against a brute force over the sphere's normals (tests/plan/test_sphere_plan.py). What it
counts is what the geometry allows, not what a pixel budget buys: a cell is filled only when some pixel's *centre*
falls in it. Two kinds of cells take far more pixels than the others:

- small θh: MERL's θh rows are 90°·(i/90)² (the first 10 rows span 1.1°, the next 10 up to 4.4°), and a cell at θh
  spans ~2·Δθh·sin θh·1° of normals, where a pixel of a sphere R pixels in radius spans ~(180/πR)° × the same (R = 19
  at 320x240: ~3°): a 320x240 frame puts one pixel centre or none in the 1,800 cells of its θd row under
  θh = 1.1°, and ~6 in the 1,800 between 1.1° and 4.4°;
- large θd: at a light–camera angle γ ≈ 2θd, the pixels kept (θi and θo ≤ 80° in the normal's frame) are a lune
  ~(180° − γ) wide seen edge-on: at 320x240 a pose gives ~320 samples at θd ≈ 50°, ~120 at 63°, ~45 at 72°, ~8 at
  77°, spread over two θd rows of 7,000–10,000 reachable cells each.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from gonio.io.merl import N_CELLS, SHAPE
from gonio.io.merl_index import half_diff_index
from gonio.sphere.geometry import Sphere, sphere_hits
from gonio.sphere.pixels import sphere_box

__all__ = ["cells_of_pose", "flat_cells_of_pose", "plan_cells", "valid_cells", "reachable_cells", "theta_d_reach",
           "theta_d_index_range", "Coverage", "plan_coverage", "band_edges_deg"]


def cells_of_pose(rig, joints, calib, sphere: Sphere, *, grazing_deg: float = 80.0, stride: int = 1) -> np.ndarray:
    """Flat MERL cell indices the sphere's pixels see at one pose (``joints``: the rig's joint angles)."""
    from gonio.pipeline.target import CameraPose

    position, R = rig.camera_pose(joints)
    pose = CameraPose(R, -R @ position)
    box = sphere_box(calib, pose, sphere)
    if box is None:
        return np.zeros(0, dtype=np.intp)
    rows, cols = box
    v, u = np.mgrid[rows, cols][:, ::stride, ::stride].astype(np.float64)
    d = calib.rays(u, v) @ pose.R
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    h, _ = sphere_hits(pose.centre, d, sphere, rig.light_position(joints))
    c = math.cos(math.radians(grazing_deg))
    ok = (h.cos_o >= c) & (h.cos_i >= c)
    ih, idd, ip = half_diff_index(h.theta_h[ok], h.theta_d[ok], h.phi_d[ok])
    return np.unique(ip + 180 * (idd + 90 * ih))


def flat_cells_of_pose(rig, joints, layout, *, n: int = 6) -> np.ndarray:
    """Flat MERL cell indices a *flat* sample fills at one pose, from the geometry alone: the (wi, wo) of an
    ``n × n`` grid of tile centres over ``layout.sample`` (normal +z; the pipeline's tiles, :mod:`gonio.pipeline.roi`,
    are about this many on the default board) — the baseline a sphere's cells are compared with before measuring."""
    from gonio.geometry import half_diff_from_dirs

    r = layout.sample
    g = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(r.x0 + g * (r.x1 - r.x0), r.y0 + g * (r.y1 - r.y0), indexing="ij")
    x = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=-1)
    cam, _ = rig.camera_pose(joints)
    wi = np.asarray(rig.light_position(joints), dtype=np.float64) - x
    wo = np.asarray(cam, dtype=np.float64) - x
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    th, _, td, pd = half_diff_from_dirs(wi[ok], wo[ok])
    ih, idd, ip = half_diff_index(th, td, pd)
    return np.unique(ip + 180 * (idd + 90 * ih))


def plan_cells(plan, rig, calib, sphere: Sphere, **kw) -> np.ndarray:
    """(N_CELLS,) bool: the cells some pose of ``plan`` fills."""
    filled = np.zeros(N_CELLS, dtype=bool)
    for j in np.asarray(plan.joints):
        filled[cells_of_pose(rig, j, calib, sphere, **kw)] = True
    return filled


@functools.lru_cache(maxsize=1)
def _cell_centre_cosines() -> tuple[np.ndarray, np.ndarray]:
    """``(cos θi, cos θo)`` (N_CELLS,) of every MERL cell centre's directions at φh = 0, read-only: the z components
    of :func:`gonio.io.merl.cell_directions`, which every process computes once from the grid's separable factors
    (~0.03 s, where :func:`gonio.geometry.dirs_from_half_diff` of the 1.46 million centres took ~0.3 s). cos θi is
    dirs_from_half_diff's to the bit; cos θo differs by at most 4.4e-16 (it takes wi·h as cos θd exactly where
    :func:`gonio.geometry.reflect` sums the dot product), while no cell's cos θi or cos θo lies within 8e-7 of 0 or
    within 1e-6 of cos 80°: the valid and reachable cells are the same (tests/plan/test_sphere_plan.py)."""
    from gonio.io.merl import cell_directions

    wi, wo, _ = cell_directions()
    cos_i, cos_o = np.ascontiguousarray(wi[..., 2]).ravel(), np.ascontiguousarray(wo[..., 2]).ravel()
    cos_i.flags.writeable = cos_o.flags.writeable = False
    return cos_i, cos_o


def valid_cells() -> np.ndarray:
    """(N_CELLS,) bool: cells whose centre directions (φh = 0) are both above the horizon."""
    cos_i, cos_o = _cell_centre_cosines()
    return (cos_i > 0) & (cos_o > 0)


def reachable_cells(theta_d_index_range, *, grazing_deg: float = 80.0) -> np.ndarray:
    """(N_CELLS,) bool: the valid cells the rig can fill (the module docstring): the cell centre's θi and θo (φh = 0;
    neither depends on φh) within ``grazing_deg`` of the normal, and its θd index within ``theta_d_index_range``
    (inclusive: the least and the largest θd index the rig's light positions give with this camera)."""
    cos_i, cos_o = _cell_centre_cosines()
    c = math.cos(math.radians(grazing_deg))
    lo, hi = (int(x) for x in theta_d_index_range)
    idd = np.broadcast_to(np.arange(SHAPE[1])[None, :, None], SHAPE).ravel()
    return valid_cells() & (cos_i >= c) & (cos_o >= c) & (idd >= lo) & (idd <= hi)


def theta_d_index_range(cells) -> tuple[int, int]:
    """(least, largest) θd index among flat MERL cell indices ``cells`` (an iterable of index arrays)."""
    idd = [np.asarray(c, dtype=np.intp) // SHAPE[2] % SHAPE[1] for c in cells if len(c)]
    if not idd:
        return 0, -1
    allc = np.concatenate(idd)
    return int(allc.min()), int(allc.max())


@dataclass
class Coverage:
    """A sphere plan's coverage: cells filled, valid, reachable, and per band (θh, θd: 9 bands of 10 index rows)."""

    filled: int
    valid: int
    reachable: int
    of_valid: float
    of_reachable: float
    theta_h_bands: list
    theta_d_bands: list
    #: (N_CELLS,) bool: the cells filled and the reachable cells (the denominators of the bands)
    filled_mask: np.ndarray = field(default=None, repr=False)
    reach_mask: np.ndarray = field(default=None, repr=False)

    def lines(self) -> list[str]:
        out = [f"coverage: {self.filled} MERL cells filled, {100 * self.of_reachable:.1f} % of the {self.reachable} "
               f"the rig can reach with the camera there, {100 * self.of_valid:.1f} % of the {self.valid} valid cells"]
        out.append("  by θh band (index rows of 10): " + " ".join(f"{100 * f:.0f}%" for f in self.theta_h_bands))
        out.append("  by θd band (9° each):          " + " ".join(f"{100 * f:.0f}%" for f in self.theta_d_bands))
        return out


def band_edges_deg(axis: int) -> list:
    """The 10 edges (degrees) of the 9 bands of 10 index rows along ``axis`` (0: θh, MERL's θh = (i/90)²·90°;
    1: θd, 9° each)."""
    i = np.arange(0, 91, 10)
    return list((i / 90.0) ** 2 * 90.0 if axis == 0 else i * 1.0)


def _bands(filled, ref, axis) -> list:
    f = filled.reshape(SHAPE)
    r = ref.reshape(SHAPE)
    out = []
    for b in range(9):
        sl = [slice(None)] * 3
        sl[axis] = slice(10 * b, 10 * b + 10)
        n = int(r[tuple(sl)].sum())
        out.append(float((f & r)[tuple(sl)].sum()) / n if n else float("nan"))
    return out


#: :func:`theta_d_reach`'s results by their arguments' values (a planner asks again for the same rig and camera: the
#: greedy plan and the coverage of the plan it made; each answer costs a traced sweep of ~650 light positions)
_REACH_CACHE: dict = {}
_REACH_CACHE_SIZE = 32


def theta_d_reach(rig, calib, sphere: Sphere, *, theta_o: float, step: float = math.radians(5.0), layout=None,
                  stride: int = 4) -> tuple[int, int]:
    """(least, largest) θd index the rig's light positions give with the camera at ``theta_o``: a sweep of the light
    every ``step`` of zenith (twice that of azimuth, up to 89°), each pose's pixels (every ``stride``-th row and
    column) traced; an extreme counts only from a pose whose frame shows the white reference
    (:data:`gonio.session.sphere_plan.MIN_WHITE_PIXELS`; checked on the most extreme poses first, so a handful of
    checks, not one per pose).

    A pure function of its arguments, all immutable (frozen dataclasses; the calibration's rays depend on its size,
    ``K`` and ``dist`` alone): remembered per process by their values, so asking again costs nothing."""
    try:
        key = (rig, int(calib.width), int(calib.height), np.asarray(calib.K, dtype=np.float64).tobytes(),
               np.asarray(calib.dist, dtype=np.float64).tobytes(), sphere, float(theta_o), float(step), layout,
               int(stride))
        hash(key)
    except TypeError:  # an argument of a kind that cannot be compared by value: computed every time
        key = None
    if key is not None and key in _REACH_CACHE:
        return _REACH_CACHE[key]
    found = _theta_d_reach(rig, calib, sphere, theta_o=theta_o, step=step, layout=layout, stride=stride)
    if key is not None:
        if len(_REACH_CACHE) >= _REACH_CACHE_SIZE:
            _REACH_CACHE.pop(next(iter(_REACH_CACHE)))
        _REACH_CACHE[key] = found
    return found


def _theta_d_reach(rig, calib, sphere: Sphere, *, theta_o: float, step: float, layout, stride: int) -> tuple[int, int]:
    """:func:`theta_d_reach`, computed."""
    from gonio.pipeline.target import CameraPose, TargetLayout
    from gonio.plan.generators import make_plan
    from gonio.session.sphere_plan import MIN_WHITE_PIXELS
    from gonio.sphere.pixels import white_seen

    dense = make_plan("sphere", rig=rig, order="raster", theta_o=theta_o, theta_i_step=step, phi_i_step=2 * step,
                      theta_max=math.radians(89))
    layout = layout or TargetLayout(sphere=sphere)
    ext = []
    for j in dense.joints:
        c = cells_of_pose(rig, j, calib, sphere, stride=stride)
        idd = c // SHAPE[2] % SHAPE[1]
        ext.append((int(idd.min()), int(idd.max())) if len(c) else (SHAPE[1], -1))
    ext = np.asarray(ext).reshape(-1, 2)

    def seen(k):
        position, R = rig.camera_pose(dense.joints[k])
        w = white_seen(calib, CameraPose(R, -R @ position), layout, rig.light_position(dense.joints[k]), sphere)
        return w is not None and int(w[2].sum()) >= MIN_WHITE_PIXELS

    lo = next((int(ext[k, 0]) for k in np.argsort(ext[:, 0], kind="stable") if ext[k, 1] >= 0 and seen(k)), 0)
    hi = next((int(ext[k, 1]) for k in np.argsort(-ext[:, 1], kind="stable") if ext[k, 1] >= 0 and seen(k)), -1)
    return lo, hi


def plan_coverage(plan, rig, calib, sphere: Sphere, *, reach_step: float = 5.0, stride: int = 1,
                  layout=None) -> Coverage:
    """The :class:`Coverage` of ``plan`` (see the module docstring); pixels every ``stride`` rows and columns. The θd
    range of the reachable cells: :func:`theta_d_reach` with a sweep every ``reach_step`` degrees, widened to the
    range a greedy plan's candidates found (``plan.params["greedy"]["theta_d_range"]``: its light positions are
    finer than the sweep), so the plan and its coverage count against the same cells."""
    filled = plan_cells(plan, rig, calib, sphere, stride=stride)
    theta_o = float(plan.params.get("theta_o", plan.poses[0, 2])) if len(plan) else 0.0
    valid = valid_cells()
    filled &= valid
    known = (plan.params.get("greedy") or {}).get("theta_d_range")  # the greedy's candidates found it: a finer sweep
    lo, hi = theta_d_reach(rig, calib, sphere, theta_o=theta_o, step=math.radians(reach_step), layout=layout)
    if known is not None:
        lo, hi = min(lo, int(known[0])), max(hi, int(known[1]))
    lo2, hi2 = theta_d_index_range([np.flatnonzero(filled)])
    reach = reachable_cells((min(lo, lo2), max(hi, hi2))) | filled
    return Coverage(int(filled.sum()), int(valid.sum()), int(reach.sum()), float(filled.sum() / valid.sum()),
                    float(filled.sum() / max(reach.sum(), 1)), _bands(filled, reach, 0), _bands(filled, reach, 1),
                    filled, reach)
