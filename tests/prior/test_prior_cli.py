"""gonio prior build/info, plan sparse, reconstruct: round trips and one-line refusals that write nothing."""

import json

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.prior import save_prior
from gonio.samples import SampleSet
from tests.prior.conftest import GRID


def _session_like_npz(path, n=40, *, f=None, sigma=None, seed=0):
    """A gonio NPZ export of ``n`` samples of a Lambert + GGX material (the samples a sparse session gives)."""
    from gonio.brdf import make
    from gonio.io.npz import build_metadata, write_npz

    rng = np.random.default_rng(seed)
    t = np.radians(rng.uniform(5, 70, (2, n)))
    p = rng.uniform(0, 2 * np.pi, n)
    wi = np.column_stack([np.sin(t[0]), np.zeros(n), np.cos(t[0])])
    wo = np.column_stack([np.sin(t[1]) * np.cos(p), np.sin(t[1]) * np.sin(p), np.cos(t[1])])
    m = make("microfacet", kd=[0.1, 0.2, 0.05], ks=[0.6] * 3, alpha=0.3, f0=[0.05] * 3)
    f = m.eval(wi, wo) if f is None else f
    sigma = 0.01 * f + 1e-5 if sigma is None else sigma
    return write_npz(path, SampleSet(wi, wo, f, sigma), build_metadata({}))


@pytest.fixture()
def prior_file(tmp_path, synthetic_prior):
    return save_prior(synthetic_prior, tmp_path / "synthetic.npz")


def test_reconstruct_round_trip_gives_an_ordinary_source(tmp_path, prior_file, capsys):
    import gonio

    src = _session_like_npz(tmp_path / "s.npz")
    out = tmp_path / "r.npz"
    assert main(["reconstruct", str(src), "--prior", str(prior_file), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fit quality: 40 samples" in text and f"wrote {out}" in text
    back = gonio.load(out)
    assert back.samples is None and back.table is not None and back.table.sigma is not None
    ok = back.table.measured
    assert ok.sum() > 500_000 and np.all(back.table.sigma[ok] > 0)
    meta = json.loads(str(np.load(out)["metadata"][0]))["reconstruction"]
    assert meta["n_samples"] == 40 and "prior" in meta and meta["dof"] == 120
    assert main(["reconstruct", str(src), "--prior", str(prior_file), "-o", str(tmp_path / "r.csv")]) != 0
    assert "must end in .npz or .binary" in capsys.readouterr().err


def test_reconstruction_as_merl_binary_reads_back(tmp_path, synthetic_prior):
    import gonio
    from gonio.prior.reconstruct import reconstruct, write_reconstruction

    post, _, _ = reconstruct(_session_like_npz(tmp_path / "s.npz"), synthetic_prior)
    table = post.table()
    out = write_reconstruction(tmp_path / "r.binary", post)
    ok = table.measured
    assert np.allclose(gonio.load(out).table.values[ok], table.values[ok], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("case", ["no_samples", "nan_value", "zero_sigma", "other_version"])
def test_bad_inputs_are_one_line_and_write_nothing(tmp_path, prior_file, capsys, case):
    src = tmp_path / "s.npz"
    prior = prior_file
    if case == "no_samples":
        from gonio.io.npz import build_metadata, write_npz

        write_npz(src, SampleSet.empty(), build_metadata({}))
    elif case == "nan_value":
        f = np.full((40, 3), 0.1)
        f[7, 2] = np.nan
        _session_like_npz(src, f=f, sigma=np.full((40, 3), 0.01))
    elif case == "zero_sigma":
        s = np.full((40, 3), 0.01)
        s[9, 0] = 0.0
        _session_like_npz(src, sigma=s)
    else:
        _session_like_npz(src)
        with np.load(prior_file) as z:
            arrays = dict(z)
        prior = tmp_path / "v2.npz"
        np.savez(prior, **{**arrays, "version": np.array(2)})
    out = tmp_path / "r.npz"
    assert main(["reconstruct", str(src), "--prior", str(prior), "-o", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    expect = {"no_samples": "no samples", "nan_value": "sample 7", "zero_sigma": "sample 9",
              "other_version": "version 2"}[case]
    assert expect in err
    assert not out.exists()


def test_sparse_plan_poses_are_all_reachable_and_reported(tmp_path, prior_file, capsys):
    from gonio.io.plan_file import read_plan_file
    from gonio.rig.kinematics import load_rig

    out = tmp_path / "plan.json"
    assert main(["plan", "sparse", "--n", "6", "--prior", str(prior_file), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "expected reconstruction error" in text and "never planned" in text
    rig = load_rig(None)
    plan = read_plan_file(out, rig)  # solves every pose again on the rig: refuses an unreachable one
    assert len(plan) == 6 and plan.generator == "sparse"
    p = plan.poses
    _, code = rig.solve_many(p[:, 0], p[:, 1], p[:, 2], p[:, 3])
    assert np.all(code == 0)
    assert 0 < plan.params["expected_error"] < plan.params["expected_error_prior"]


def test_sparse_plan_never_picks_an_unreachable_candidate(synthetic_prior):
    """Even when the prior would most like an unreachable direction, only reachable candidates are chosen."""
    from gonio.prior.design import candidate_poses, sparse_plan
    from gonio.rig.kinematics import load_rig

    rig = load_rig(None)
    cand = candidate_poses(rig)
    assert cand.n_dropped > 0  # the default rig has collisions and a camera shadow among the candidates
    plan = sparse_plan(25, synthetic_prior, rig=rig)
    dropped = {tuple(np.round(d["pose"], 9)) for d in cand.dropped}
    assert not any(tuple(np.round(q, 9)) in dropped for q in plan.poses)
    _, code = rig.solve_many(*plan.poses.T)
    assert np.all(code == 0)


def test_prior_build_and_info_from_tables(tmp_path, capsys):
    from gonio.brdf import make
    from gonio.io.merl import MerlTable, cell_directions, write_merl

    wi, wo, above = cell_directions()
    paths = []
    for i, (kd, alpha) in enumerate([(0.1, 0.2), (0.3, 0.5), (0.05, 0.3)]):
        v = np.full(above.shape + (3,), np.nan)
        v[above] = make("microfacet", kd=[kd] * 3, ks=[0.5] * 3, alpha=alpha, f0=[0.05] * 3).eval(wi[above], wo[above])
        paths.append(write_merl(tmp_path / f"t{i}.binary", MerlTable(v)))
    out = tmp_path / "prior.npz"
    assert main(["prior", "build", *map(str, paths), "-o", str(out)]) == 0
    assert "3 materials" in capsys.readouterr().out
    assert main(["prior", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "t0, t1, t2" in text and "gonio-prior/1" in text
    assert main(["prior", "build", str(paths[0]), "-o", str(tmp_path / "one.npz")]) != 0
    assert "at least 2" in capsys.readouterr().err


def test_sparse_plan_options_are_checked(prior_file, capsys):
    assert main(["plan", "sparse", "--n", "5", "--theta-step", "10", "--prior", str(prior_file)]) != 0
    assert "not a parameter of plan 'sparse'" in capsys.readouterr().err
    assert main(["plan", "half_diff", "--n", "5"]) != 0
    assert "only for plan sparse" in capsys.readouterr().err
    assert main(["plan", "sparse", "--n", "0", "--prior", str(prior_file)]) != 0
    assert "must be in [1, 1000]" in capsys.readouterr().err


def test_flagged_samples_are_left_out_before_they_are_checked(tmp_path, synthetic_prior):
    """A saturated sample (flagged) is not used, so its value does not refuse the source; the rest are used."""
    from gonio.io.npz import build_metadata, write_npz
    from gonio.prior.reconstruct import measured_samples

    import gonio

    good = gonio.load(_session_like_npz(tmp_path / "g.npz")).samples
    f = good.f.copy()
    f[3] = np.nan
    flags = np.zeros(len(f), dtype=np.int64)
    flags[3] = 1
    src = write_npz(tmp_path / "s.npz", SampleSet(good.wi, good.wo, f, good.sigma, flags=flags), build_metadata({}))
    _, used = measured_samples(src)
    assert len(used) == len(f) - 1 and np.isfinite(used.f).all()


def test_measure_a_sparse_plan_on_the_simulated_rig_and_reconstruct_it(tmp_path, prior_file, capsys):
    """The whole chain: gonio measure --plan sparse (expected error said before anything moves), gonio reconstruct
    of the session (as a MERL table: the NPZ with σ is the round trip above), read back as a table."""
    import gonio

    session = tmp_path / "s"
    assert main(["measure", "--sim", "--plan", "sparse", "--n", "3", "--prior", str(prior_file), "--out",
                 str(session), "--quiet"]) == 0
    assert gonio.load(session).manifest["plan"]["generator"] == "sparse"
    out = tmp_path / "r.binary"
    assert main(["reconstruct", str(session), "--prior", str(prior_file), "-o", str(out)]) == 0
    assert "fit quality:" in capsys.readouterr().out
    assert gonio.load(out).table.measured.sum() > 500_000
