"""Measurement plans: which poses to measure, in which order, and how long it will take.

A :class:`Plan` is data (docs/architecture.md §7): ordered poses ``(θi, φi, θo, φo)`` in radians, capture settings,
the generator and its parameters, and the poses dropped as unreachable with their reasons. Build one
with :func:`make_plan` (generators in :data:`GENERATORS`), estimate its lab time with
:func:`estimate_plan`, or grow one adaptively with :func:`gonio.plan.adaptive.adaptive_plan` (measure, fit, add poses
where the model is uncertain or fits worst, stop at a target error or a lab-time budget).
"""

from __future__ import annotations

from gonio.plan.generators import GENERATORS, Generator, PlanParam, make_plan, solve_plan_joints
from gonio.plan.labtime import LabAccount, SessionTiming, session_lab_time
from gonio.plan.ordering import (LabTimeEstimate, MotionModel, estimate, mst_move_time, optimize_order,
                                 raster_order)
from gonio.plan.plan import CaptureSettings, Plan


def _plan_joints(plan: Plan, rig):
    joints = plan.joints
    if joints is None:
        joints, reasons = solve_plan_joints(rig, plan.poses)
        bad = [i for i, r in enumerate(reasons) if r is not None]
        if bad:
            from gonio.errors import ConfigError

            raise ConfigError.field(None, f"plan.poses[{bad[0]}]", plan.poses[bad[0]].tolist(),
                                    f"unreachable on rig {rig.name!r} ({reasons[bad[0]]})")
    return joints


def _rig(rig):
    from gonio.rig.kinematics import Rig, load_rig

    return rig if isinstance(rig, Rig) else load_rig(rig)


def plan_move_times(plan: Plan, rig=None, *, start=None, indices=None, sequential: bool = False):
    """Move time before each pose of ``plan`` (or of ``plan.poses[indices]``, in that order), seconds:
    from ``start`` (joint vector) to the first pose (0 when ``start`` is None), then pose to pose, at the
    speeds the servos run (:meth:`MotionModel.as_run`)."""
    import numpy as np

    rig = _rig(rig)
    model = MotionModel.as_run(rig)  # the servos' profiles as written (slower than stated: rounded down)
    q = np.asarray(_plan_joints(plan, rig), dtype=np.float64)
    if indices is not None:
        q = q[np.asarray(indices, dtype=np.int64)]
    fn = model.sequential_move_time if sequential else model.move_time
    first = np.zeros(min(len(q), 1)) if start is None else fn(np.asarray(start, dtype=np.float64)[None, :], q[:1])
    return np.concatenate([first, fn(q[:-1], q[1:]) if len(q) > 1 else np.zeros(0)])


def estimate_plan(plan: Plan, rig=None, timing: SessionTiming | None = None, *, start=None) -> LabTimeEstimate:
    """Lab time of a session measuring ``plan`` in its order on ``rig`` (default rig if None), under the
    runner's cost model (:func:`gonio.plan.labtime.session_lab_time`: start-up darks and warm-up,
    moves, settle, metering frame + bracket with readout, dark re-measurements), with a true lower
    bound (MST of the moves, every other cost at its minimum) and the raster, one-axis-at-a-time
    baseline. With automatic exposure the capture time uses the plan's expected bracket."""
    import numpy as np

    rig = _rig(rig)
    joints = _plan_joints(plan, rig)
    model = MotionModel.from_rig(rig)
    n = len(plan)
    cap = plan.capture
    moves = plan_move_times(plan, rig, start=start)
    raster = raster_order(plan.poses)
    mst = mst_move_time(joints, model, start=start)
    acc = session_lab_time(moves, cap, timing)
    low = session_lab_time(np.full(n, mst / max(n, 1)), cap, timing, bound=True)
    ras = session_lab_time(plan_move_times(plan, rig, start=start, indices=raster, sequential=True), cap, timing)
    ras_c = session_lab_time(plan_move_times(plan, rig, start=start, indices=raster), cap, timing)
    return LabTimeEstimate(n_poses=n, pose_time=cap.pose_time(), optimized=acc.total, lower_bound=low.total,
                           raster=ras.total, raster_concurrent=ras_c.total, startup=acc.startup,
                           auto_exposure=cap.auto_exposure, account=acc.to_dict())


__all__ = ["Plan", "CaptureSettings", "GENERATORS", "Generator", "PlanParam", "make_plan", "solve_plan_joints",
           "MotionModel", "LabTimeEstimate", "estimate", "estimate_plan",
           "plan_move_times", "SessionTiming", "LabAccount", "session_lab_time", "optimize_order", "raster_order"]
