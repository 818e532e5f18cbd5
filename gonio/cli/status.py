"""``gonio status DIR``: what a session directory holds and how far it got."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("status", help="summarize a session directory",
                       description="Print a session's plan size, samples done, poses remaining, lab time so far, "
                                   "exit status, and whether a torn last record will be dropped on resume.")
    p.add_argument("dir", metavar="DIR", help="session directory")
    p.set_defaults(func=run)


def session_status(directory) -> dict:
    """The facts ``gonio status`` prints, as a dict (read-only; nothing in DIR changes)."""
    from pathlib import Path

    from gonio.store.directory import (_killed_run, _read_manifest, _samples_path, missing_poses, plan_pose_count,
                                     poses_beyond_plan, scan_samples)

    d = Path(directory)
    manifest = _read_manifest(d)
    scan = scan_samples(_samples_path(d, manifest))
    plan = manifest.get("plan") or {}
    n_plan = plan_pose_count(manifest)  # None for a crafted or damaged plan: unknown, not a loop over 10**30 poses
    beyond = poses_beyond_plan(manifest, scan.records)
    done = set(scan.records) - set(beyond)
    # per-record lab clock (the runner writes meta["lab_time_s"]); a finished run also leaves its total
    lab = [m.get("lab_time_s", m.get("lab_time")) for _, m in scan.records.values()]
    lab = [t for t in lab if _seconds(t) is not None]
    last_run = manifest.get("last_run") if isinstance(manifest.get("last_run"), dict) else {}
    runs_list = manifest.get("runs") if isinstance(manifest.get("runs"), list) else []
    runs = [r.get("lab_time_s") for r in runs_list if isinstance(r, dict)]
    runs = [t for t in runs if _seconds(t) is not None]
    current = _killed_run(manifest, scan)  # a run in progress or killed: its records' lab time so far
    if runs or current is not None:  # every finished (or killed) run recorded its lab time: the session's total
        lab_time = float(sum(runs)) + (current["lab_time_s"] if current else 0.0)
    elif manifest.get("exit_status"):  # older sessions kept the last run's only
        lab_time = _seconds(last_run.get("lab_time_s", manifest.get("lab_time")))
    else:
        lab_time = max(lab) if lab else None
    return {
        "material": manifest.get("material"),
        "plan": plan.get("generator") if isinstance(plan, dict) else None,
        "plan_poses": n_plan,
        "poses_done": len(done),
        "samples": sum(len(s) for p, (s, _) in scan.records.items() if p in done),
        "beyond_plan": beyond,  # records of poses the plan does not have: not counted, not loaded
        "remaining": None if n_plan is None else sum(1 for i in range(n_plan) if i not in done),
        "lab_time": lab_time,  # seconds, summed over the finished runs
        "lab_time_runs": len(runs) + (current is not None),  # runs that sum covers (0: older session)
        "exit_status": manifest.get("exit_status"),
        "started": manifest.get("started"),
        "stopped": manifest.get("stopped"),
        "resumes": len(manifest["resumes"]) if isinstance(manifest.get("resumes"), list) else 0,
        "duplicates": scan.n_duplicates,
        "torn": scan.torn,
        "failed_poses": [(k, why) for k, why in _failed_poses(manifest) if k not in done],
        "damaged": scan.describe_damage() if scan.damaged else None,
        "n_damaged": len(scan.damaged),
        "missing_poses": missing_poses(manifest, len(scan.records) + len(scan.damaged)),
    }



def _seconds(value) -> float | None:
    """A lab time read from the manifest or a record as a finite number of seconds, else None (a hand-edited
    ``"abc"``, ``NaN`` or ``1e308`` twice is not a lab time: it reads as unknown, never a traceback or ``nan s``)."""
    import math

    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) and 0 <= value <= 1e9 else None


def _failed_poses(manifest) -> list[tuple[int, str]]:
    """``(pose, reason)`` of the poses the last run could not measure for bad camera frames, from its
    summary (checked: a hand-edited manifest gives what is readable, never a traceback)."""
    run = manifest.get("last_run")
    failed = run.get("failed") if isinstance(run, dict) else None
    out = []
    for x in failed if isinstance(failed, list) else ():  # a number or a string there is not a list of poses
        if isinstance(x, dict) and isinstance(x.get("pose"), int) and not isinstance(x.get("pose"), bool):
            out.append((x["pose"], str(x.get("reason", ""))[:200]))
    return out


def run(args) -> int:
    from gonio.io.material_toml import describe_material

    s = session_status(args.dir)
    print(f"session {args.dir}: material {describe_material(s['material'])}, plan {s['plan'] or 'unknown'}")
    print(f"plan poses:   {s['plan_poses'] if s['plan_poses'] is not None else 'unknown'}")
    print(f"poses done:   {s['poses_done']} ({s['samples']} samples)")
    print(f"remaining:    {s['remaining'] if s['remaining'] is not None else 'unknown'}")
    lab = s["lab_time"]
    n = s["lab_time_runs"]
    over = f" over {n} runs" if n > 1 else ""
    if n and s["exit_status"] is None:
        over += " (+ the run in progress, not yet recorded)"
    elif not n and s["resumes"] and lab is not None:
        over = " (last run only: earlier runs' lab time was not recorded)"
    print(f"lab time:     {'unknown' if lab is None else f'{lab:.1f} s'}{over}")
    status = s["exit_status"] or "none (still running, or killed: resume with `gonio resume DIR`)"
    print(f"exit status:  {status}")
    print(f"started:      {s['started']}; stopped: {s['stopped'] or '-'}; resumed {s['resumes']} time(s)")
    if s["beyond_plan"]:
        b = s["beyond_plan"]
        print(f"NOT IN PLAN: {len(b)} record(s) of poses the plan does not have (pose "
              f"{', '.join(map(str, b[:5]))}{' …' if len(b) > 5 else ''}): not counted, and left out when the "
              "session is read (another session's records, or an edited file?)")
    if s["missing_poses"]:
        print(f"MISSING: {s['missing_poses']} pose(s) the manifest counted at its last stop are not in samples.jsonl "
              "(a truncated or replaced file?); restore it from a backup, or `gonio resume DIR` measures them again")
    if s["duplicates"]:
        print(f"note: {s['duplicates']} pose(s) recorded more than once; the last record of each is used")
    if s["failed_poses"]:
        print(f"failed poses: {len(s['failed_poses'])} not measured, bad camera frames (`gonio resume DIR` "
              "measures them again):")
        for k, why in s["failed_poses"][:20]:
            print(f"  pose {k}: {why}")
        if len(s["failed_poses"]) > 20:
            print(f"  ... and {len(s['failed_poses']) - 20} more")
    if s["torn"]:
        print(f"note: torn last record ({s['torn']}); it will be dropped on resume and the pose re-measured")
    if s["n_damaged"]:
        print(f"note: {s['n_damaged']} damaged record(s): {s['damaged']}; every other sample is used; "
              f"`gonio repair {args.dir}` (or resume) moves them to quarantine.jsonl and their poses are measured again")
    return 0
