"""No output lands on a session's own files; an existing file is not overwritten without --force; the fit
result is written before an optional export that can fail."""

from __future__ import annotations

import hashlib
import json
import os

import pytest

from gonio.cli.main import main




def _digest(d):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir" for p in sorted(d.iterdir())}


@pytest.mark.parametrize("argv", [
    ["export", "{s}", "--format", "npz", "-o", "{s}/samples.jsonl"],
    ["export", "{s}", "--format", "npz", "-o", "{s}/x.npz"],
    ["export", "{s}", "--format", "csv", "-o", "{s}/manifest.json"],
    ["export", "{s}", "--format", "merl", "-o", "{link}"],
    ["fit", "{s}", "--model", "lambert", "--json", "{s}/manifest.json"],
    ["fit", "{s}", "--model", "lambert", "--json", "{s}/../s/samples.jsonl"],
    ["plot", "{s}", "--kind", "coverage", "-o", "{s}/cov.png"],
    ["plan", "in_plane", "--out", "{s}/manifest.json"],
    ["tabulate", "{s}", "-o", "{s}/t.binary"],
    ["measure", "--sim", "--quiet", "--out", "{s}/inner"],
    ["calibrate", "rig", "--sim", "--quick", "--quiet", "--out", "{s}/cal.toml"],
    ["calibrate", "check", "--sim", "--quiet", "--session", "{s}/check"],
])
def test_no_output_lands_in_a_session(session, tmp_path, capsys, argv):
    link = tmp_path / "innocent.binary"
    os.symlink(session / "samples.jsonl", link)  # a link pointing into the session
    before = _digest(session)
    code = main([a.format(s=session, link=link) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "session" in err[0], err
    assert _digest(session) == before  # nothing changed, nothing added


def test_existing_file_needs_force_and_the_fit_json_comes_first(session, tmp_path, capsys):
    out = tmp_path / "t.csv"
    out.write_text("precious\n")
    assert main(["export", str(session), "--format", "csv", "-o", str(out)]) == 2
    assert "exists (use --force" in capsys.readouterr().err and out.read_text() == "precious\n"
    assert main(["export", str(session), "--format", "csv", "-o", str(out), "--force"]) == 0
    assert out.read_text().startswith("theta_i_deg")
    # --mitsuba refuses a model it cannot represent exactly: the JSON result is already written
    fit_json = tmp_path / "fit.json"
    code = main(["fit", str(session), "--model", "microfacet", "--json", str(fit_json),
                 "--mitsuba", str(tmp_path / "m.xml")])
    assert json.loads(fit_json.read_text())["model"] == "microfacet"
    assert code == 0 or not (tmp_path / "m.xml").exists()
    # an output option that names an existing file is refused before the fit runs, not after
    assert main(["fit", str(session), "--model", "microfacet", "--json", str(fit_json)]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.fixture(scope="module")
def exports(session, tmp_path_factory):
    """A CSV and a filled MERL export (with its sidecar) of the session."""
    d = tmp_path_factory.mktemp("exports")
    assert main(["export", str(session), "--format", "csv", "-o", str(d / "in.csv")]) == 0
    assert main(["tabulate", str(session), "--fill", "10", "-o", str(d / "t.binary")]) == 0
    return d


@pytest.mark.parametrize("argv", [
    ["export", "{d}/in.csv", "--format", "csv", "-o", "{d}/in.csv", "--force"],
    ["export", "{d}/in.csv", "--format", "csv", "-o", "{d}/./in.csv", "--force"],
    ["fit", "{d}/in.csv", "--model", "lambert", "--json", "{d}/in.csv", "--force"],
    ["export", "{d}/t.binary", "--format", "merl", "-o", "{d}/t.binary", "--force"],
    ["export", "{d}/t.binary", "--format", "csv", "-o", "{d}/t.binary.json", "--force"],
    ["export", "{d}/t.binary", "{d}/in.csv", "--format", "npz", "-o", "{d}/npz", "--summary", "{d}/in.csv", "--force"],
    ["export", "{d}/t.binary", "{d}/in.csv", "--format", "npz", "-o", "{d}/npz", "--summary", "{s}/samples.jsonl"],
    ["export", "{d}/t.binary", "{d}/in.csv", "--format", "npz", "-o", "{s}/npz"],
    ["fit", "{d}/t.binary", "{d}/in.csv", "--model", "lambert", "--json", "{s}"],
])
def test_no_output_replaces_an_input_even_with_force(session, exports, capsys, argv):
    """Output path = an input (or a MERL input's sidecar, or a session for a batch's directory or summary):
    one line naming the option, exit 2, every input and the session unchanged, nothing created."""
    before, files = _digest(session), _digest(exports)
    code = main([a.format(s=session, d=exports) for a in argv] + ["--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "an input of this command" in err[0] or "session directory" in err[0], err
    assert _digest(session) == before and _digest(exports) == files


def test_tabulate_writes_the_sidecar_so_filled_cells_are_not_taken_for_measurements(exports):
    from gonio.io.source import load_source

    src = load_source(exports / "t.binary")
    assert (exports / "t.binary.json").is_file()
    assert src.filled is not None and src.filled.sum() > 0


def test_a_batch_names_two_sources_with_one_name_apart(session, tmp_path, capsys):
    """a/s and b/s would both be s.npz: each is named with its parent directory, and the run says so (one output
    never replaces the other; tests/api/test_batch_outputs.py for fit, plot and the checks before the run)."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for sub in ("a", "b"):
        os.symlink(session, tmp_path / sub / "s")
    code = main(["export", str(tmp_path / "a" / "s"), str(tmp_path / "b" / "s"), "--format", "npz",
                 "-o", str(tmp_path / "out"), "--quiet", "--summary", str(tmp_path / "sum.csv")])
    out = capsys.readouterr().out
    assert code == 0 and "each is named with its parent directories" in out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a-s.npz", "b-s.npz"]


def test_a_session_that_did_not_finish_is_said_so_when_loaded(session, tmp_path, capsys):
    """An interrupted or killed session still loads (its samples are real), with one warning line saying
    how much of the plan it holds and the resume command; a completed one loads silently."""
    import shutil
    import warnings

    import gonio

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gonio.load(session)  # completed: no warning
    half = tmp_path / "half"
    shutil.copytree(session, half)
    lines = (half / "samples.jsonl").read_bytes().splitlines(keepends=True)
    (half / "samples.jsonl").write_bytes(b"".join(lines[:2]))
    manifest = json.loads((half / "manifest.json").read_text())
    manifest["exit_status"] = None  # killed in its first run: the manifest counted nothing yet
    manifest["pose_count"] = manifest["sample_count"] = 0
    (half / "manifest.json").write_text(json.dumps(manifest))
    with pytest.warns(UserWarning, match=r"not complete \(no exit status: killed, or still running\): 2 of \d+ poses"):
        assert len(gonio.load(half).samples) > 0
    assert main(["tabulate", str(half)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: warning:") and f"gonio resume {half}" in err[0], err


def test_a_session_directory_refused_names_the_option_that_chose_it(session, capsys):
    assert main(["calibrate", "check", "--sim", "--quiet", "--session", str(session)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--session" in err[0] and "--out" not in err[0], err


def test_an_export_interrupted_while_writing_leaves_the_previous_file(session, tmp_path, monkeypatch):
    """Ctrl-C (or a full disk) in the middle of writing --force over an export: the old file stays whole and no
    half-written file (a CSV cut at a line boundary reads as a smaller, valid one) takes its name."""
    import numpy as np

    out = tmp_path / "e.csv"
    assert main(["export", str(session), "--format", "csv", "-o", str(out)]) == 0
    before = out.read_bytes()
    real = np.savetxt

    def savetxt_then_interrupt(fh, *a, **kw):
        real(fh, *a, **kw)
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savetxt", savetxt_then_interrupt)
    assert main(["export", str(session), "--format", "csv", "-o", str(out), "--force"]) == 130
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["e.csv"]
