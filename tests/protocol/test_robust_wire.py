"""Small version of the robustness benchmark's wire section: damaged frames through both decoders."""

from benchmarks.robust_wire import run_wire_fuzz


def test_damaged_frames_never_accepted_and_decoders_agree_segment_for_segment():
    rows = run_wire_fuzz(3000, quick=True)
    both, c_stream = rows
    assert both["segments"] >= 3000 and c_stream["frames"] >= 20_000
    for r in rows:
        assert r["crashes"] == 0 and r["corrupt_accepted"] == 0
    assert both["disagreements"] == 0 and c_stream["disagreements"] == "lost resync 0"
