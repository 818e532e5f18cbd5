"""Measurement plans: which poses to measure, in which order, and how long it will take.

A :class:`Plan` is data (DESIGN.md §6): ordered poses ``(θi, φi, θo, φo)`` in radians, capture settings,
the generator and its parameters, and the poses dropped as unreachable with their reasons. Build one
with :func:`make_plan` (generators in :data:`GENERATORS`), estimate its lab time with
:func:`estimate_plan`, or grow one adaptively with :func:`gonio.plan.adaptive.adaptive_plan` (measure, fit, add poses
where the model is uncertain or fits worst, stop at a target error or a lab-time budget).
"""

from __future__ import annotations

from gonio.plan.generators import GENERATORS, Generator, PlanParam, make_plan, solve_plan_joints
from gonio.plan.ordering import LabTimeEstimate, MotionModel, estimate, optimize_order, raster_order
from gonio.plan.plan import CaptureSettings, Plan


def estimate_plan(plan: Plan, rig=None) -> LabTimeEstimate:
    """Lab time of ``plan`` in its order on ``rig`` (default rig if None), with the MST lower bound
    and the raster, one-axis-at-a-time baseline (:func:`gonio.plan.ordering.estimate`)."""
    import numpy as np

    from gonio.rig.kinematics import Rig, load_rig

    rig = rig if isinstance(rig, Rig) else load_rig(rig)
    joints = plan.joints
    if joints is None:
        joints, reasons = solve_plan_joints(rig, plan.poses)
        bad = [i for i, r in enumerate(reasons) if r is not None]
        if bad:
            from gonio.errors import ConfigError

            raise ConfigError.field(None, f"plan.poses[{bad[0]}]", plan.poses[bad[0]].tolist(),
                                    f"unreachable on rig {rig.name!r} ({reasons[bad[0]]})")
    return estimate(plan.poses, joints, np.arange(len(plan)), MotionModel.from_rig(rig), plan.capture.pose_time())


__all__ = ["Plan", "CaptureSettings", "GENERATORS", "Generator", "PlanParam", "make_plan", "solve_plan_joints",
           "MotionModel", "LabTimeEstimate", "estimate", "estimate_plan", "optimize_order", "raster_order"]
