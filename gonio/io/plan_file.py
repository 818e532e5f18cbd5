"""Plan files: what ``gonio plan NAME --out PLAN.json`` writes and ``gonio measure --plan-file PLAN.json``
runs.

The file is :meth:`gonio.plan.plan.Plan.to_dict` as JSON: ``{"format": 1, "units": "rad",
"generator", "params", "capture", "order", "n_poses", "poses": [[θi, φi, θo, φo], ...], "joints",
"dropped"}``. On read it is untrusted input: its size is bounded, every field is checked
(:meth:`Plan.from_dict`: format version, units, shapes, finite numbers, capture settings), and every
pose is solved again on the rig the session runs on — a plan written for another rig, or edited by hand
to an unreachable pose, is refused in one line naming the pose and the reason, before anything moves.
The joint angles the runner uses are the ones solved here, never the file's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gonio.errors import DataError

__all__ = ["read_plan_file", "MAX_BYTES"]

MAX_BYTES = 64 * 2 ** 20


def read_plan_file(path, rig):
    """The :class:`gonio.plan.plan.Plan` in ``path``, validated and solved on ``rig``. ``path`` may also be a
    session directory or its ``manifest.json``: the session's plan (its ``plan`` field) is measured again."""
    from dataclasses import replace

    from gonio.plan.generators import solve_plan_joints
    from gonio.plan.plan import Plan

    p = Path(path)
    if p.is_dir() and (p / "manifest.json").is_file():
        p = p / "manifest.json"
    try:
        size = p.stat().st_size
        if size > MAX_BYTES:
            raise DataError(f"{p}: plan file of {size} bytes (more than {MAX_BYTES}): not a plan")
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataError(f"{p}: cannot read the plan file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        from gonio.io.sniff import describe

        raise DataError(f"{p}: not a plan file: it looks like {describe(p)}") from None
    try:
        data = json.loads(text)
    except ValueError as exc:
        from gonio.io.sniff import describe

        raise DataError(f"{p}: not a plan file (not JSON: {exc.msg} at line {exc.lineno}); it looks like "
                        f"{describe(p)}") from None
    if isinstance(data, dict) and "samples_file" in data and isinstance(data.get("plan"), dict):
        data = data["plan"]  # a session's manifest: the plan it ran (formats.md §5: the same object)
    plan = Plan.from_dict(data, source=str(p))
    if len(plan) == 0:
        raise DataError(f"{p}: the plan has no pose")
    poses = plan.poses
    if poses.ndim != 2 or poses.shape[1] != 4 or not np.all(np.isfinite(poses)):
        raise DataError(f"{p}: poses must be finite [theta_i, phi_i, theta_o, phi_o] rows (radians)")
    joints, reasons = solve_plan_joints(rig, poses)
    bad = [k for k, r in enumerate(reasons) if r is not None]
    if bad:
        k = bad[0]
        deg = ", ".join(f"{x:.3g}" for x in np.degrees(poses[k]))
        hint = (f"was the plan made for another rig? it says {plan.params.get('rig', 'nothing')!r}"
                if np.abs(poses).max() <= 2 * np.pi else
                f"angles up to {np.abs(poses).max():.4g} in a file whose angles are radians: were degrees written?")
        raise DataError(f"{p}: pose {k} ({deg} deg) is unreachable on rig {rig.name!r} ({reasons[k]}); "
                        f"{len(bad)} of {len(plan)} poses are ({hint})")
    return replace(plan, joints=joints)
