"""The compiled BRDF path: the lobe formulas of :mod:`gonio.brdf.pairs` run per pair in a numba loop.

numba is a core dependency (issue 31.5; ``gonio --version`` says which path runs); :mod:`gonio.brdf.pairs` (NumPy) stays the reference, and the
two agree to ≤ 1e-12 relative (tests/brdf/test_compiled.py). Nothing here is a formula: the loop calls
the :func:`gonio._jit.jitable` functions the NumPy path calls — :func:`gonio.brdf.pairs.pair_geometry`,
the lobes' spec functions (:data:`SPECS`) and :func:`gonio.brdf.fresnel.schlick_m` — which numba compiles
from their Python source (``register_jitable``). Why a compiled loop: a NumPy expression makes one pass
over memory per operation (≈ 60 for a GGX lobe, most of them on 10⁶-element temporaries), a loop makes one
pass for the whole model and keeps every intermediate in registers, and the lobes of a sum share the
geometry of each pair (python -m benchmarks brdf).

A model has a compiled form when it is written as lobes (:meth:`gonio.brdf.base.BRDF._lobes`) whose spec
functions are all in :data:`SPECS`: ``microfacet`` (GGX, Beckmann), ``cook-torrance``, ``gtr``, ``abc``,
``abc-smooth``, ``ashikhmin-shirley``, ``lambert`` and sums of them. Each loop is compiled on first use and its machine code
kept on disk, keyed by a hash of the formulas' source (:func:`_cached_module`), so later processes load it in milliseconds.
"""

from __future__ import annotations

import functools
import importlib.util
import os

import numpy as np

from gonio.brdf.abc import abc_smooth_spec, abc_smooth_spec_split, abc_spec, abc_spec_split
from gonio.brdf.ashikhmin_shirley import ashikhmin_shirley_diffuse, ashikhmin_shirley_spec, ashikhmin_shirley_spec_split
from gonio.brdf.cook_torrance import cook_torrance_spec
from gonio.brdf.gtr import gtr_spec, gtr_spec_split
from gonio.brdf.microfacet import beckmann_spec, ggx_spec

__all__ = ["MIN_PAIRS", "SPECS", "available", "supports", "wanted", "evaluate"]

#: Spec functions the kernel dispatches on, by index (the kernel's if-chain follows this order).
SPECS = (ggx_spec, beckmann_spec, cook_torrance_spec, gtr_spec, abc_spec, ashikhmin_shirley_spec,
         ashikhmin_shirley_diffuse, abc_smooth_spec)
#: Spec functions whose one transcendental is a :func:`gonio._jit.power`, and their split forms
#: ``(base, exponent, factor)`` (the spec is :func:`gonio.brdf.pairs.split_value` of it): the loop calls the split
#: form and the power itself (:data:`_LOBE_SPLIT`), so the power's code (:func:`gonio._vmath.vpower`) is inlined
#: into the loop and LLVM vectorizes it; called inside a spec function it stays a call (LLVM's inliner leaves a
#: function that large alone), which keeps the loop scalar, 1.5–2× slower. (numba's own ``inline="always"`` on
#: the spec functions would do it too, but compiles a kernel in 6–15 s instead of < 1 s.)
SPLIT = {abc_spec: abc_spec_split, abc_smooth_spec: abc_smooth_spec_split, gtr_spec: gtr_spec_split,
         ashikhmin_shirley_spec: ashikhmin_shirley_spec_split}
#: Most shape parameters of a spec function.
MAX_PARAMS = 3
#: ``backend="auto"`` uses the compiled loop from this many pairs on (below, the call overhead of
#: either path dominates and NumPy avoids importing numba).
MIN_PAIRS = 512
#: ... and, while the model's loop is not yet in this process, from this many pairs on: the first use of a loop
#: loads numba and the loop's machine code (0.3–0.6 CPU s from the disk cache), which NumPy's ~50 ns a pair repays
#: only on arrays this large (a selection evaluates each of its candidates once or twice on 2·10⁴ samples: compiling
#: them cost it ~0.8 s of its 10 s budget; a 512² viewer frame or a MERL table's 9·10⁵ cells still compile).
COLD_PAIRS = 200_000
#: Loops already in this process (``kinds`` of :func:`_kernel`): using them again costs nothing.
_LOADED: set = set()
_TINY = float(np.finfo(np.float64).tiny)


@functools.lru_cache(maxsize=None)
def available() -> bool:
    """numba is installed (the ``fast`` extra)."""
    return importlib.util.find_spec("numba") is not None


def describe_path() -> str:
    """Which BRDF evaluation path runs, for ``gonio --version``: ``compiled (numba X.Y)`` — for float64 arrays of
    :data:`MIN_PAIRS` pairs or more of the models that have a compiled form — or ``NumPy`` and why (numba not
    installed, or ``GONIO_BRDF_BACKEND=numpy``). numba is not imported to say so."""
    if not available():
        return "NumPy (numba is not installed: pip install numba for the compiled path)"
    if os.environ.get("GONIO_BRDF_BACKEND", "auto") == "numpy":
        return "NumPy (GONIO_BRDF_BACKEND=numpy)"
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("numba")
    except PackageNotFoundError:  # importable but not installed as a distribution (a source tree on the path)
        v = "unknown version"
    return f"compiled (numba {v})"


def _pack(model):
    """Arrays the kernel takes for ``model`` (cached on the immutable model), or None without a compiled form."""
    cached = model.__dict__.get("_compiled_pack", False)
    if cached is not False:
        return cached
    pack = None
    desc = model._lobes()
    if desc is not None and all(lobe.spec in SPECS for lobe in desc[1]):
        const, lobes = desc
        n = len(lobes)
        kinds = tuple(SPECS.index(lobe.spec) for lobe in lobes)
        params = np.zeros((n, MAX_PARAMS))
        w, f0 = np.zeros((n, 3)), np.ones((n, 3))
        for j, lobe in enumerate(lobes):
            params[j, :len(lobe.params)] = lobe.params
            w[j] = lobe.weight
            if lobe.f0 is not None:
                f0[j] = lobe.f0
        pack = (kinds, params, w, f0, np.broadcast_to(np.asarray(const, dtype=np.float64), (3,)).copy())
    object.__setattr__(model, "_compiled_pack", pack)
    return pack


def supports(model) -> bool:
    """``model`` has a compiled form (whether or not numba is installed)."""
    return _pack(model) is not None


def wanted(model, wi, dtype, backend: str) -> bool:
    """Whether :meth:`~gonio.brdf.base.BRDF.eval` with ``backend`` should use the compiled loop."""
    if backend == "compiled":
        if dtype != np.float64:
            raise ValueError("the compiled BRDF path is float64 only")
        if not available():
            raise ValueError("the compiled BRDF path needs numba: pip install numba")
        if not supports(model):
            raise ValueError(f"model {model.name!r} has no compiled form")
        return True
    if dtype != np.float64 or wi.size < 3 * MIN_PAIRS or os.environ.get("GONIO_BRDF_BACKEND", "auto") == "numpy":
        return False
    if not (available() and supports(model)):
        return False
    return wi.size >= 3 * COLD_PAIRS or _pack(model)[0] in _LOADED


def evaluate(model, wi, wo) -> np.ndarray:
    """f(wi, wo) of ``model`` by the compiled loop; ``wi``, ``wo`` float64 arrays of one shape ``(..., 3)``."""
    shape = wi.shape[:-1]
    a = np.ascontiguousarray(wi).reshape(-1)
    b = np.ascontiguousarray(wo).reshape(-1)
    out = np.empty(a.shape[0])
    kinds, *arrays = _pack(model)
    _kernel(kinds)(a, b, *arrays, out)
    _LOADED.add(kinds)
    return out.reshape(shape + (3,))


@functools.lru_cache(maxsize=None)
def _register():
    """Register the jitable functions (and the scalar :func:`gonio._jit.select` and :func:`gonio._jit.power`)
    with numba, once."""
    import numba
    from numba.extending import overload, register_jitable

    from gonio import _jit

    @overload(_jit.select)
    def _select(cond, a, b):
        if isinstance(cond, numba.types.Boolean):
            return lambda cond, a, b: a if cond else b
        return None

    @overload(_jit.power, jit_options={"error_model": "numpy"}, inline="always")
    def _power(base, exponent):
        if isinstance(base, numba.types.Float) and isinstance(exponent, numba.types.Float):
            from gonio._vmath import vpower

            return lambda base, exponent: vpower(base, exponent)
        return None

    for fn in _jit.JITABLE:
        register_jitable(error_model="numpy")(fn)
    return numba


_LOOP = """
def loop(wi, wo, params, w, f0, const, out):
    r0_, r1_, r2_ = const[0], const[1], const[2]
{setup}
    for i in range(wi.shape[0] // 3):
        ix, iy, iz = wi[3 * i], wi[3 * i + 1], wi[3 * i + 2]
        ox, oy, oz = wo[3 * i], wo[3 * i + 1], wo[3 * i + 2]
        above = (iz > 0.0) & (oz > 0.0)
        p = pair_geometry(ix, iy, iz, ox, oy, oz, TINY)
        r0, r1, r2 = r0_, r1_, r2_
{lobes}
        out[3 * i] = select(above, r0, 0.0)
        out[3 * i + 1] = select(above, r1, 0.0)
        out[3 * i + 2] = select(above, r2, 0.0)
"""
#: The loop of a model without lobes (``lambert``: a constant above the horizon). Only cos θi, cos θo are read,
#: so a branch-free body would be vectorized with gathers (one of every three values), several times slower than
#: this scalar loop.
_LOOP_CONST = """
def loop(wi, wo, params, w, f0, const, out):
    r0, r1, r2 = const[0], const[1], const[2]
    for i in range(wi.shape[0] // 3):
        if wi[3 * i + 2] > 0.0 and wo[3 * i + 2] > 0.0:
            out[3 * i] = r0
            out[3 * i + 1] = r1
            out[3 * i + 2] = r2
        else:
            out[3 * i] = 0.0
            out[3 * i + 1] = 0.0
            out[3 * i + 2] = 0.0
"""
_SETUP = """
    w{j}0, w{j}1, w{j}2 = w[{j}, 0], w[{j}, 1], w[{j}, 2]
    f{j}0, f{j}1, f{j}2 = f0[{j}, 0], f0[{j}, 1], f0[{j}, 2]
    p{j}0, p{j}1, p{j}2 = params[{j}, 0], params[{j}, 1], params[{j}, 2]"""
_VALUE = """
        s = {spec}(p, {params})"""
_LOBE = """{value}
        r0 += w{j}0 * (s * schlick_m(f{j}0, p.m))
        r1 += w{j}1 * (s * schlick_m(f{j}1, p.m))
        r2 += w{j}2 * (s * schlick_m(f{j}2, p.m))"""
#: A lobe in :data:`SPLIT`: its split form, then the power and product of :func:`gonio.brdf.pairs.split_value`.
_SPLIT = """
        y, e, s = {spec}(p, {params})
        s = power(y, e) * s"""
#: numba options: ``error_model="numpy"`` (a float division by zero gives inf/nan as in NumPy, not an
#: exception; the formulas guard their divisions anyway).
_OPTIONS = {"nogil": True, "error_model": "numpy"}


@functools.lru_cache(maxsize=None)
def _kernel(kinds: tuple):
    """The loop for lobes of spec functions ``SPECS[k] for k in kinds``, compiled on first use.

    Generated from :data:`_LOOP`: one block per lobe, so each sum's loop is straight-line code (no dispatch
    per pair), with the lobes' parameters read before the loop (what depends on them alone is computed once,
    not per pair). Schlick's factor is applied to every lobe (f0 = 1 for lobes without one gives F = 1
    exactly). The loop body has no branch: every pair is evaluated and the horizon applied by ``select`` at
    the store (below the horizon the formulas may give anything, even NaN, which the select discards), and
    the arrays are flat (``3 i + c``, a constant stride), so LLVM vectorizes the loop (AVX2: 4 pairs per
    instruction, ``vsqrtpd``/``vdivpd``); a ``continue`` for pairs below the horizon, or ``(n, 3)`` arrays
    (a stride unknown at compile time), keep it scalar and 3–7× slower (python -m benchmarks brdf).
    The machine code is kept on disk (:func:`_cached_module`), so a new process loads it instead
    of compiling again.
    """
    numba = _register()
    setup, blocks, imports = [], [], []
    for k in sorted(set(kinds)):
        fn = SPLIT.get(SPECS[k], SPECS[k])
        imports.append(f"from {fn.__module__} import {fn.__name__} as spec{k}")
    for j, k in enumerate(kinds):
        nparam = SPECS[k].__code__.co_argcount - 1
        setup.append(_SETUP.format(j=j))
        value = (_SPLIT if SPECS[k] in SPLIT else _VALUE).format(spec=f"spec{k}",
                                                                   params=", ".join(f"p{j}{q}" for q in range(nparam)))
        blocks.append(_LOBE.format(value=value, j=j))
    source = "\n".join([
        "# Generated by gonio.brdf.compiled (a numba loop over the formulas it imports); do not edit.",
        "from gonio._jit import power, select", "from gonio.brdf.fresnel import schlick_m",
        "from gonio.brdf.pairs import pair_geometry", *imports,
        f"TINY = {_TINY!r}", _LOOP.format(setup="".join(setup), lobes="".join(blocks)) if kinds else _LOOP_CONST])
    module = _cached_module(source, numba.__version__)
    if module is not None:
        return numba.njit(cache=True, **_OPTIONS)(module.loop)
    namespace = {}
    exec(source, namespace)
    return numba.njit(**_OPTIONS)(namespace["loop"])


def _cached_module(source: str, numba_version: str):
    """The generated loop as a module in the kernel cache directory (``$GONIO_KERNEL_CACHE``, default
    ``$XDG_CACHE_HOME/gonio/brdf-kernels``; ``off`` for none), where numba's cache keeps its machine code.

    The file name is a hash of the loop's source, of every module holding a jitable formula (their
    functions and constants), of :mod:`gonio._jit` and :mod:`gonio._vmath` (what ``select`` and ``power`` compile
    to) and of the NumPy and numba versions: a change in any formula gives a new file
    and a fresh compilation (numba's own cache would not notice a change in a called function). None when
    the directory is off or not writable: the loop is then compiled in memory, once per process.
    """
    import hashlib
    import importlib.util
    import inspect
    import sys
    from pathlib import Path

    from gonio import _jit

    where = os.environ.get("GONIO_KERNEL_CACHE", "")
    if where == "off":
        return None
    digest = hashlib.sha256(source.encode())
    import gonio._vmath  # noqa: F401 - its source is part of the key: power() compiles to it

    for name in sorted({fn.__module__ for fn in _jit.JITABLE} | {"gonio._jit", "gonio._vmath"}):
        digest.update(inspect.getsource(sys.modules[name]).encode())
    digest.update(f"{np.__version__} {numba_version}".encode())
    key = digest.hexdigest()[:24]
    try:
        folder = Path(where) if where else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gonio" / "brdf-kernels"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"loop_{key}.py"
        if not path.exists():
            tmp = folder / f".loop_{key}.{os.getpid()}.tmp"
            tmp.write_text(source)
            os.replace(tmp, path)  # atomic: concurrent processes write the same text
        spec = importlib.util.spec_from_file_location(f"gonio_brdf_loop_{key}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # numba's cached code refers to its module by name
        spec.loader.exec_module(module)
        return module
    except (OSError, ImportError):
        return None
