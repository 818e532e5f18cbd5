"""gonio.io.merl_index's exact pass (the pairs whose MERL cell depends on the last bits of acos/atan2/cos/sin) runs
the C library's functions in a compiled loop once a process has computed enough values one Python call at a time:
the same bits as Python's math module (which wraps the same functions), or the Python path where they would differ."""

from __future__ import annotations

import math

import numpy as np

import gonio.io.merl_index as M


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return a.shape == b.shape and bool(np.all((a.view(np.int64) == b.view(np.int64)) | (np.isnan(a) & np.isnan(b))))


def test_the_compiled_loops_are_the_c_library_s_functions_bit_for_bit():
    from gonio.io import _libm

    assert _libm.exact()
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(-7, 7, 20_000), rng.normal(0, 1e-9, 2_000), _libm.CHECK,
                        1 - np.abs(rng.normal(0, 1e-13, 2_000)), rng.uniform(-1, 1, 20_000)])
    y = rng.permutation(x)
    for name, f in (("cos", math.cos), ("sin", math.sin), ("acos", math.acos)):
        want = [M._c_call(f)(v) for v in x]
        assert _same_bits(_libm.FUNCTIONS[name](x.copy()), want), name
    assert _same_bits(_libm.FUNCTIONS["atan2"](y.copy(), x.copy()), [M._c_call(math.atan2)(a, b) for a, b in zip(y, x)])


def _pole_pairs(n, seed=0):
    """``n`` pairs wi = wo (every one near the pole of the difference vector: all of them recomputed), and as many
    within 1e-9 of it."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    w = v + rng.normal(0, 1e-9, v.shape)
    return np.concatenate([v, v]), np.concatenate([v, w])


def test_the_exact_pass_gives_the_same_cells_and_angles_on_either_path(monkeypatch):
    wi, wo = _pole_pairs(3_000)
    monkeypatch.setattr(M, "_warm", lambda: M._compiled.cache_info().currsize > 0)  # as if numba were not loaded
    monkeypatch.setattr(M, "_PYTHON_VALUES", [0])
    monkeypatch.setattr(M, "COLD_VALUES", 10**15)  # never loaded: the Python path
    M._compiled.cache_clear()
    python = M.reference_half_diff(wi, wo)
    assert M._PYTHON_VALUES[0] >= 8 * len(wi)  # every pair went through the C functions one value at a time
    assert M._compiled.cache_info().currsize == 0
    monkeypatch.setattr(M, "COLD_VALUES", 0)  # loaded on the first call
    counted = M._PYTHON_VALUES[0]
    compiled = M.reference_half_diff(wi, wo)
    assert M._PYTHON_VALUES[0] == counted and M._compiled() is not None  # the loop ran, not the Python path
    for a, b in zip(python, compiled):
        assert _same_bits(a, b)
    for a, b in zip(M.half_diff_index(python[0], python[2], python[3]),
                    M.half_diff_index(compiled[0], compiled[2], compiled[3])):
        assert np.array_equal(a, b)
    M._compiled.cache_clear()


def test_the_python_path_counts_until_the_loop_pays_and_stays_where_the_loop_is_not_exact(monkeypatch):
    from gonio.io import _libm

    monkeypatch.setattr(M, "_warm", lambda: M._compiled.cache_info().currsize > 0)  # as if numba were not loaded
    monkeypatch.setattr(M, "_PYTHON_VALUES", [0])
    monkeypatch.setattr(M, "COLD_VALUES", 1_000)
    M._compiled.cache_clear()
    assert M._loops(600) is None and M._PYTHON_VALUES[0] == 600  # not yet: computed in Python and counted
    assert M._loops(10) is None  # below MIN_COMPILED: always Python
    assert M._loops(500) is not None  # 600 + 10 + 500 >= 1,000: loaded from now on
    assert M._loops(M.MIN_COMPILED) is not None and M._PYTHON_VALUES[0] == 610
    M._compiled.cache_clear()
    monkeypatch.undo()
    monkeypatch.setattr(M, "_PYTHON_VALUES", [0])
    monkeypatch.setattr(_libm, "exact", lambda: False)  # e.g. numba vectorizing with SVML: never the loop
    assert M._warm() and M._loops(10**7) is None  # numba is here, but its loops are not the C library's
    wi, wo = _pole_pairs(50, seed=1)
    counted = M._PYTHON_VALUES[0]
    th, ph, td, pd = M.reference_half_diff(wi, wo)
    assert M._PYTHON_VALUES[0] == counted + 8 * len(wi) and np.isfinite(th).all() and np.isfinite(ph).all()
    M._compiled.cache_clear()


def test_with_numba_in_the_process_the_loop_runs_from_the_first_call(monkeypatch):
    import numba  # noqa: F401  (as the compiled BRDF path and the simulator import it in a process)
    monkeypatch.setattr(M, "_PYTHON_VALUES", [0])
    M._compiled.cache_clear()
    assert M._loops(M.MIN_COMPILED) is not None and M._loops(M.MIN_COMPILED - 1) is None
    assert M._PYTHON_VALUES[0] == M.MIN_COMPILED - 1
