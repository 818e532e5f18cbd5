"""A sphere's plan chosen for the cells it fills per lab second (issue 30): greedy weighted set cover.

Candidates are the light positions of a dense ``sphere`` plan (the camera fixed at ``theta_o``; every pose the rig
reaches without collision or shadow, :func:`gonio.plan.generators.make_plan`) whose frame shows the white reference
(not in the sphere's shadow: :data:`MIN_WHITE_PIXELS`). Each candidate's MERL cells come from
the geometry alone (:func:`gonio.session.sphere_coverage.cells_of_pose`, valid cells only); the *reachable* cells
are those the rig can fill at all (:func:`gonio.session.sphere_coverage.reachable_cells`, more than the candidates'
pixels fill: each candidate is one sample of a continuum of light positions). From the rig's rest position, the plan takes, again and again, the candidate with the most cells
not yet filled per lab second it costs — its capture and settle (:func:`gonio.plan.labtime.pose_capture_time`) plus
the move from the pose taken last (:class:`gonio.plan.ordering.MotionModel`) — until ``coverage`` of the reachable
cells are filled or no pose fits in what is left of the lab-time ``budget``. This is the greedy algorithm for
weighted (budgeted) set cover (Chvátal 1979, "A greedy heuristic for the set-covering problem", Math. Oper.
Res. 4(3); within ``ln n`` of the fewest seconds), evaluated lazily: a candidate's count of new cells only falls as cells fill, so a stale count
is an upper bound (Minoux 1978, "Accelerated greedy algorithms for maximizing submodular set functions"). The poses
taken are then ordered for lab time as any plan is (:func:`gonio.plan.ordering.optimize_order`); the ordered tour
moves less than the greedy counted (each move from the pose taken before), and the lab time it frees goes back to
the greedy (:data:`REFILLS`), so the plan fills its budget: the session's lab time as
:func:`gonio.plan.estimate_plan` counts it (start-up darks and dark checks included) stays within the budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError
from gonio.io.merl import N_CELLS
from gonio.session.sphere_coverage import (cells_of_pose, reachable_cells, theta_d_index_range, theta_d_reach,
                                           valid_cells)
from gonio.sphere.geometry import Sphere

__all__ = ["greedy_sphere_plan", "sweep_cells", "MIN_WHITE_PIXELS"]

#: A candidate whose frame shows fewer white-reference pixels than this (the sphere's shadow on the patch, the sphere
#: in front of it: :func:`gonio.sphere.pixels.white_seen`) is not planned: the frame could not be calibrated
MIN_WHITE_PIXELS = 16

#: Rounds of refill: the greedy counts each pose's move from the pose taken before it, the plan is then ordered as a
#: tour (:func:`gonio.plan.ordering.optimize_order`) that moves less; the lab time that frees is given back to the
#: greedy, at most this many times (on the default rig the 20-minute plan's first round leaves ~10 % of it unused)
REFILLS = 3


def greedy_sphere_plan(rig, calib, sphere: Sphere, *, theta_o: float = math.radians(60),
                       theta_i_step: float = math.radians(2.5), phi_i_step: float = math.radians(10),
                       theta_max: float = math.radians(89), coverage: float = 0.9, budget: float = 1200.0,
                       capture=None, stride: int = 1, seed: int = 0, layout=None, sweep=None,
                       reach_step: float = math.radians(5.0)):
    """``(plan, info)``: the greedy plan of the module docstring and what it expects (``reachable`` and ``filled``
    cell counts, ``candidates_reach``: the cells all candidates together fill, ``lab_s`` estimated for the poses
    taken in the plan's order as :func:`gonio.plan.estimate_plan` counts a session (start-up darks, captures,
    settles, the moves of the ordered tour, dark checks), ``candidates``, ``trace``:
    (poses, 2) lab seconds and cells filled after each pose taken, in the greedy's order, each move counted from the
    pose taken before — the coverage against lab time curve, an upper bound of the lab time). The lab time the
    ordered tour saves goes back to the greedy (:data:`REFILLS`). It stops at ``coverage`` of the reachable cells, at the ``budget``, or when no
    candidate adds a cell. ``sweep``: the candidates and their cells, :func:`sweep_cells`'s result with the same
    arguments (a caller planning twice computes them once). ``reach_step``: the light sweep's step that finds the
    reachable θd range (:func:`gonio.session.sphere_coverage.theta_d_reach`)."""
    from gonio.plan.labtime import pose_capture_time, session_lab_time
    from gonio.plan.ordering import MotionModel, optimize_order
    from gonio.plan.plan import CaptureSettings

    if not (0.0 < coverage <= 1.0):
        raise ConfigError.field(None, "--coverage", coverage, "must be in (0, 1]")
    if not (budget > 0 and math.isfinite(budget)):
        raise ConfigError.field(None, "--lab-budget", budget, "must be positive seconds")
    capture = capture or CaptureSettings()
    cand, cells = sweep or sweep_cells(rig, calib, sphere, theta_o=theta_o, theta_i_step=theta_i_step,
                                       phi_i_step=phi_i_step, theta_max=theta_max, stride=stride, layout=layout,
                                       capture=capture)
    reach = np.zeros(N_CELLS, dtype=bool)
    for c in cells:
        reach[c] = True
    n_cand = int(reach.sum())
    lo, hi = theta_d_index_range(cells)
    lo2, hi2 = theta_d_reach(rig, calib, sphere, theta_o=theta_o, layout=layout, step=reach_step)  # as plan_coverage counts them
    reach = reachable_cells((min(lo, lo2), max(hi, hi2))) | reach  # what the rig can fill: more than the candidates
    need = coverage * int(reach.sum())
    if n_cand == 0:
        raise ConfigError.field(None, "plan sphere", f"{len(cand)} candidates",
                                f"no light position shows the sphere and {MIN_WHITE_PIXELS} white-reference pixels")
    model = MotionModel.as_run(rig)  # the servos' profiles as written, as the lab-time estimate moves them
    per_pose = float(capture.settle) + pose_capture_time(capture)
    joints = np.asarray(cand.joints, dtype=np.float64)
    gain = np.array([len(c) for c in cells], dtype=np.float64)  # upper bounds of the new cells (lazy)
    st = _Greedy(np.zeros(N_CELLS, dtype=bool), [], 0.0, 0, [], None, np.ones(len(cells), dtype=bool), gain)
    overhead = session_lab_time(np.zeros(1), capture).total - per_pose  # the session's start-up darks, warm-up
    limit, best, rounds, retries = budget - overhead, None, 0, 0
    while rounds <= REFILLS and retries < 8:
        trial = st.copy()
        trial.run(cells, joints, model, per_pose, need, limit)
        if not trial.taken or len(trial.taken) == len(st.taken):
            break
        taken = np.asarray(trial.taken)
        perm = optimize_order(joints[taken], model, seed=seed, initial=np.arange(len(taken)))
        q = joints[taken][perm]
        tour = session_lab_time(np.concatenate([[0.0], model.move_time(q[:-1], q[1:])]), capture).total
        if tour > budget + 1e-9:  # the poses added last do not fit the session: retry with less
            limit = max(limit - 1.1 * (tour - budget) - per_pose, st.spent)
            retries += 1
            continue
        st, best, rounds = trial, (perm, tour), rounds + 1
        if st.n_cov >= need or tour > budget - per_pose:
            break
        limit += budget - tour  # the greedy counted each move from the pose taken before; the tour moves less
    if best is None:
        raise ConfigError.field(None, "--fill-budget", budget, f"less than the session's start-up and one pose "
                                f"({overhead + per_pose:.1f} lab s)")
    perm, tour = best
    taken = st.taken
    plan = cand.reordered(np.array(taken + [k for k in range(len(cand)) if k not in set(taken)]), "raster")
    from dataclasses import replace

    sub = replace(plan, poses=plan.poses[:len(taken)], joints=plan.joints[:len(taken)],
                  params={**plan.params, "greedy": {"coverage": coverage, "budget_s": budget,
                                                     "candidates": len(cand),
                                                     "theta_d_range": [min(lo, lo2), max(hi, hi2)]}})
    sub = sub.reordered(perm, "optimized")
    info = {"reachable": int(reach.sum()), "filled": int(st.n_cov), "lab_s": tour, "candidates": len(cand),
            "poses": len(taken), "candidates_reach": n_cand, "trace": np.asarray(st.trace, dtype=np.float64)}
    return sub, info


@dataclass
class _Greedy:
    """The greedy's state: cells covered, candidates taken (in order), lab seconds spent as it counts them, cells
    filled, ``trace`` (spent, filled) per pose, the pose taken last, the candidates still open, and their gains (upper
    bounds of their new cells: lazy evaluation, Minoux 1978)."""

    covered: np.ndarray
    taken: list
    spent: float
    n_cov: int
    trace: list
    current: object
    open_: np.ndarray
    gain: np.ndarray

    def copy(self) -> "_Greedy":
        return _Greedy(self.covered.copy(), list(self.taken), self.spent, self.n_cov, list(self.trace),
                       self.current, self.open_.copy(), self.gain.copy())

    def run(self, cells, joints, model, per_pose: float, need: float, limit: float) -> None:
        """Take, again and again, the open candidate with the most new cells per lab second (its capture and settle
        ``per_pose`` plus the move from the pose taken last), while ``need`` cells are not filled, a candidate adds a
        cell and the lab seconds spent stay within ``limit``."""
        gain = self.gain
        while self.n_cov < need and self.open_.any():
            cost = per_pose + (0.0 if self.current is None else
                               model.move_time(np.broadcast_to(self.current, joints.shape), joints))
            cost = np.broadcast_to(np.asarray(cost, dtype=np.float64), gain.shape)
            can = self.open_ & (self.spent + cost <= limit)  # never past the budget
            if not can.any():
                return
            while True:
                ratio = np.where(can, gain / cost, -np.inf)
                i = int(np.argmax(ratio))
                true = float(np.count_nonzero(~self.covered[cells[i]]))
                gain[i] = true
                ratio[i] = true / cost[i]
                if ratio[i] >= np.max(np.where(np.arange(len(ratio)) == i, -np.inf, ratio), initial=-np.inf):
                    break
            if gain[i] <= 0:
                return
            self.covered[cells[i]] = True
            self.n_cov += int(gain[i])
            self.spent += float(cost[i])
            self.taken.append(i)
            self.trace.append((self.spent, self.n_cov))
            self.open_[i] = False
            self.current = joints[i]


def sweep_cells(rig, calib, sphere: Sphere, *, theta_o: float, theta_i_step: float, phi_i_step: float,
                theta_max: float, stride: int = 1, layout=None, capture=None):
    """``(plan, cells)``: a regular sweep of the light (a ``sphere`` plan, raster order) and, per pose, the valid
    MERL cells its pixels fill (:func:`gonio.session.sphere_coverage.cells_of_pose`); none at a pose whose frame
    shows fewer than :data:`MIN_WHITE_PIXELS` of the white reference (the patch in the sphere's shadow or behind it:
    the frame could not be calibrated)."""
    from gonio.pipeline.target import CameraPose, TargetLayout
    from gonio.plan.generators import make_plan
    from gonio.sphere.pixels import white_seen

    cand = make_plan("sphere", rig=rig, capture=capture, order="raster", theta_o=theta_o, theta_i_step=theta_i_step,
                     phi_i_step=phi_i_step, theta_max=theta_max)
    layout = layout or TargetLayout(sphere=sphere)
    valid = valid_cells()
    cells = []
    for j in cand.joints:
        position, R = rig.camera_pose(j)
        seen = white_seen(calib, CameraPose(R, -R @ position), layout, rig.light_position(j), sphere)
        if seen is None or int(seen[2].sum()) < MIN_WHITE_PIXELS:  # the white patch shadowed or hidden
            cells.append(np.zeros(0, dtype=np.intp))
            continue
        c = cells_of_pose(rig, j, calib, sphere, stride=stride)
        cells.append(c[valid[c]])
    return cand, cells
