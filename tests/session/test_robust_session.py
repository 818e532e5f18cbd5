"""The small version of benchmarks/robust_session.py (the full one: ``python -m benchmarks.robust_session``):
kill -9 + resume loses and duplicates nothing, mutated session files give no traceback and lose no good
sample, camera frame faults end completed or with one line and a resume hint, never with wrong samples."""

from __future__ import annotations

from benchmarks import robust_session as rs


def test_kill_9_at_random_instants_then_resume_loses_and_duplicates_nothing():
    (row,) = rs.run_kill_resume(2, quick=True, seed=5)
    what, runs, tracebacks, not_resumable, lost, duplicated = row
    assert runs == 2 and (tracebacks, not_resumable, lost, duplicated) == (0, 0, 0, 0), row


def test_mutated_manifests_and_records_give_no_traceback_and_lose_no_good_sample():
    rows = rs.run_mutated_session_files(6, quick=True, seed=7)
    assert [r[0] for r in rows] == ["manifest fields", "samples records"]
    for what, n, commands, tracebacks, lost in rows:
        assert commands >= 3 * n and tracebacks == 0 and lost == 0, (what, tracebacks, lost)


def test_frame_faults_complete_or_stop_in_one_line_and_never_store_wrong_samples():
    rows = rs.run_frame_faults(1, quick=True)
    for spec, n, completed, stopped, tracebacks, wrong in rows:
        assert completed + stopped == n and tracebacks == 0 and wrong == 0, (spec, completed, stopped, wrong)
    assert dict((r[0], r[2]) for r in rows)["black=1"] == 0  # a dead camera never ends "completed"
