"""The BRDF model contract shared by every model in :mod:`gonio.brdf` (docs/architecture.md §3, §6).

A model is a small immutable object: ``eval(wi, wo) -> ndarray[..., 3]`` in 1/sr (RGB), ``params``
(a dict), ``bounds()`` for fitting, and a name in the registry (:func:`gonio.brdf.make`).
Below the horizon (cos θ ≤ 0 for wi or wo) the value is 0, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar, Mapping

import numpy as np

from gonio.errors import ConfigError

#: Largest | |w|² − 1 | of a direction :meth:`BRDF.eval` accepts (float32 directions round to ~1e-7).
UNIT_TOLERANCE = 1e-5
#: Directions :meth:`BRDF.eval` checks per call: all of a small call, evenly spaced ones of a large call (a
#: caller that forgets to normalize does so everywhere; a full check would cost a third of a compiled evaluation)
UNIT_CHECKED = 1024


def check_unit(w: np.ndarray, name: str) -> None:
    """``w`` (..., 3) holds unit vectors — all of them up to :data:`UNIT_CHECKED`, else that many evenly spaced —
    or a ValueError naming ``name``, the first offending pair and its length (a non-unit direction scales most
    models' values silently: Ward's halves for |wi| = 2)."""
    if w.shape[-1:] != (3,):
        raise ValueError(f"{name}: directions must be (..., 3) arrays, got shape {w.shape}")
    flat = w.reshape(-1, 3)
    n = len(flat)
    rows = flat if n <= UNIT_CHECKED else flat[:: -(-n // UNIT_CHECKED)]
    r2 = np.einsum("ij,ij->i", rows, rows, dtype=np.float64)
    bad = np.flatnonzero(~(np.abs(r2 - 1.0) <= UNIT_TOLERANCE))
    if bad.size:
        k = int(bad[0]) * (1 if n <= UNIT_CHECKED else -(-n // UNIT_CHECKED))
        raise ValueError(f"{name}: directions must be unit vectors; pair {k} has length {np.sqrt(r2[bad[0]]):.6g} "
                         "(normalize them, e.g. gonio.geometry.normalize)")


@dataclass(frozen=True)
class Param:
    """Specification of one model parameter.

    Attributes
    ----------
    kind : {"rgb", "scalar", "choice", "table"}
        ``rgb`` accepts a scalar or 3 values and is stored as shape ``(3,)``; ``scalar`` is one
        float; ``choice`` is one of ``choices`` (a string, not fitted); ``table`` is a tabulated function
        (a data-driven model's, :mod:`gonio.brdf.dupuy`): ``cols == 0`` a list of 2 to :data:`TABLE_MAX`
        values, ``cols == 3`` a list of as many rows of R, G, B.
    lo, hi : float
        Valid closed range (also the fitting bounds); ``hi`` may be ``inf``.
    default : object
        Value used when the parameter is omitted; ``None`` means required.
    doc : str
        One line: meaning and unit.
    """

    kind: str
    lo: float = 0.0
    hi: float = np.inf
    default: Any = None
    choices: tuple[str, ...] = ()
    doc: str = ""
    cols: int = 0

    def coerce(self, model: str, name: str, value: Any, source: str | None = None) -> Any:
        """Validate and convert ``value``; raise :class:`ConfigError` naming model, field and value."""
        field = f"{model}.{name}"
        if self.kind == "choice":
            if value not in self.choices:
                raise ConfigError.field(source, field, value, f"must be one of {', '.join(self.choices)}")
            return value
        if _not_numeric(value):  # True is not 1, "0.5" is not 0.5: a TOML or JSON typo, refused
            raise ConfigError.field(source, field, value, "must be a number (not a string or a boolean)")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError.field(source, field, value, "must be a number") from None
        if self.kind == "table":
            want = (1,) if self.cols == 0 else (2, self.cols)
            if arr.ndim != len(want) or (self.cols and arr.shape[1] != self.cols) or not 2 <= len(arr) <= TABLE_MAX:
                rows = "numbers" if self.cols == 0 else f"rows of {self.cols} numbers"
                raise ConfigError.field(source, field, _short(value), f"must be a list of 2 to {TABLE_MAX} {rows}")
            if not np.all(np.isfinite(arr)) or np.any(arr < self.lo) or np.any(arr > self.hi):
                raise ConfigError.field(source, field, _short(value), f"every entry must be finite and in "
                                                                      f"[{self.lo:g}, {self.hi:g}]")
            arr = arr.copy()
            arr.setflags(write=False)
            return arr
        if self.kind == "rgb":
            if arr.ndim == 0:
                arr = np.full(3, float(arr))
            if arr.shape != (3,):
                raise ConfigError.field(source, field, value, "must be a number or 3 numbers (R, G, B)")
        elif arr.ndim != 0:
            raise ConfigError.field(source, field, value, "must be a single number")
        if not np.all(np.isfinite(arr)) or np.any(arr < self.lo) or np.any(arr > self.hi):
            raise ConfigError.field(source, field, value, f"must be finite and in [{self.lo:g}, {self.hi:g}]")
        if self.kind == "rgb":
            arr = arr.copy()
            arr.setflags(write=False)
            return arr
        return float(arr)


#: Most entries of a ``table`` parameter.
TABLE_MAX = 1024


def _short(value: Any) -> str:
    """A table value for a one-line message (its start)."""
    text = str(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 60 else text[:57] + "..."


def _not_numeric(value: Any) -> bool:
    """Booleans and strings (also inside a list) are not numbers, though NumPy would convert them."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return True
    if isinstance(value, (list, tuple)):
        return any(_not_numeric(v) for v in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "bUSO" and (value.dtype.kind != "O" or any(_not_numeric(v) for v in value.flat))
    return False


class BRDF:
    """Base class of analytic BRDF models.

    Subclasses set :attr:`name`, :attr:`PARAMS` and implement :meth:`_eval`, which receives unit
    directions already known to be above the horizon (the base class zeroes the rest) and returns
    RGB values of shape ``(..., 3)``. Parameters are validated once, at construction, and the object
    is immutable afterwards.
    """

    #: Registry name (``gonio.brdf.make(name, ...)``).
    name: ClassVar[str] = ""
    #: Parameter specifications, in a stable order.
    PARAMS: ClassVar[Mapping[str, Param]] = MappingProxyType({})
    #: f(wi, wo) = f(wo, wi) for every parameter value.
    reciprocal: ClassVar[bool] = True
    #: Invariant under rotation of both directions about the normal.
    isotropic: ClassVar[bool] = True
    #: Directional albedo ≤ 1 for physical parameters (kd + ks ≤ 1 etc.), as the model is normalized.
    energy_conserving: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs):
        """Freeze a subclass's ``PARAMS`` (written as a dict literal) into a read-only mapping."""
        super().__init_subclass__(**kwargs)
        if not isinstance(cls.__dict__.get("PARAMS", MappingProxyType({})), MappingProxyType):
            cls.PARAMS = MappingProxyType(dict(cls.PARAMS))

    def __init__(self, *, _source: str | None = None, **params: Any):
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            raise ConfigError.field(
                _source, f"{self.name}.{unknown[0]}", params[unknown[0]],
                f"unknown parameter; {self.name} takes {', '.join(self.PARAMS)}",
            )
        values = {}
        for key, spec in self.PARAMS.items():
            if key in params:
                value = params[key]
            elif spec.default is not None:
                value = spec.default
            else:
                raise ConfigError(
                    f"{_source + ': ' if _source else ''}{self.name}: missing parameter {key!r} ({spec.doc})"
                )
            values[key] = spec.coerce(self.name, key, value, _source)
        object.__setattr__(self, "_params", MappingProxyType(values))
        self._validate()

    def _validate(self) -> None:
        """Hook for checks across parameters (raise :class:`ConfigError`)."""

    def __setattr__(self, key, value):
        raise AttributeError(f"{type(self).__name__} is immutable; use .replace(...)")

    def __getattr__(self, key):
        params = self.__dict__.get("_params")
        if params is not None and key in params:
            return params[key]
        raise AttributeError(key)

    @property
    def params(self) -> dict[str, Any]:
        """Parameter values: RGB as lists of 3 floats, scalars as floats, choices as strings."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self._params.items()}

    def replace(self, **changes: Any) -> "BRDF":
        """A copy with some parameters changed."""
        return type(self)(**{**self._params, **changes})

    @classmethod
    def bounds(cls) -> dict[str, tuple[float, float]]:
        """Fitting bounds ``(lo, hi)`` of every numeric parameter."""
        return {k: (p.lo, p.hi) for k, p in cls.PARAMS.items() if p.kind not in ("choice", "table")}

    def eval(self, wi, wo, dtype=np.float64, backend: str = "auto") -> np.ndarray:
        """BRDF value f(wi, wo) in 1/sr, RGB on the last axis, shape ``broadcast(wi, wo)[:-1] + (3,)``.

        ``wi`` (toward the light) and ``wo`` (toward the camera) are unit vectors in the local frame (checked:
        :func:`check_unit`, ValueError otherwise). Where either is at or below the horizon the result is exactly 0.

        ``dtype`` (default float64) is the floating type of the computation and the result;
        ``np.float32`` evaluates with float32 inputs and parameters (faster, less accurate: see
        ``python -m benchmarks brdf``). The finiteness guarantees at the extremes are for float64.

        ``backend``: ``"numpy"`` the NumPy reference path; ``"compiled"`` the numba-compiled loop of
        :mod:`gonio.brdf.compiled` (float64 only; numba, a core dependency; ValueError if it
        cannot be used); ``"auto"`` (default) the compiled loop for float64 arrays of
        ≥ :data:`gonio.brdf.compiled.MIN_PAIRS` pairs when numba is installed, the model has a compiled
        form and its loop is already loaded in this process (or the array has ≥
        :data:`gonio.brdf.compiled.COLD_PAIRS` pairs, which repay loading it), else NumPy. Both give the same values (≤ 1e-12 relative, a test). The environment variable
        ``GONIO_BRDF_BACKEND=numpy`` makes ``"auto"`` mean NumPy.
        """
        dtype = np.dtype(dtype)
        if backend not in ("auto", "numpy", "compiled"):
            raise ValueError(f"backend must be 'auto', 'numpy' or 'compiled', not {backend!r}")
        wi = np.asarray(wi, dtype=dtype)
        wo = np.asarray(wo, dtype=dtype)
        check_unit(wi, "wi")
        check_unit(wo, "wo")
        wi, wo = np.broadcast_arrays(wi, wo)
        if backend != "numpy":
            from gonio.brdf import compiled

            if compiled.wanted(self, wi, dtype, backend):
                return compiled.evaluate(self, wi, wo)
        above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
        model = self if dtype == np.float64 else self._astype(dtype)
        with np.errstate(all="ignore"):
            value = np.broadcast_to(model._eval(wi, wo), wi.shape[:-1] + (3,))
        return np.where(above[..., None], value, dtype.type(0.0))

    def _lobes(self):
        """``(const, [Lobe, ...])`` when the model is ``const + Σ lobes`` on shared pair geometry
        (:mod:`gonio.brdf.pairs`; such models get a compiled form), else None."""
        return None

    def _astype(self, dtype) -> "BRDF":
        """A twin whose numeric parameters are of ``dtype`` (for :meth:`eval` with ``dtype``)."""
        twin = object.__new__(type(self))
        cast = {k: (v if isinstance(v, str) else np.asarray(v, dtype=dtype)[()]) for k, v in self._params.items()}
        object.__setattr__(twin, "_params", MappingProxyType(cast))
        return twin

    def _eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Values above the horizon; models written as lobes (:meth:`_lobes`) need not override it."""
        lobes = self._lobes()
        if lobes is None:  # pragma: no cover - abstract
            raise NotImplementedError
        from gonio.brdf.pairs import evaluate

        return evaluate(*lobes, wi, wo)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
        return f"{self.name}({args})"

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and all(
            np.array_equal(a, b) for a, b in zip(self._params.values(), other._params.values())
        )

    __hash__ = None  # type: ignore[assignment]
