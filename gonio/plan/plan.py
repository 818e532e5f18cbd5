"""The :class:`Plan` data type: ordered poses + capture settings + how they were made (docs/architecture.md §7,
"plans are data").

A plan is computed, inspected, estimated and checked against the rig's limits before anything moves.
It round-trips through a plain JSON-able dict (:meth:`Plan.to_dict` / :meth:`Plan.from_dict`), which
is what the session manifest stores, so a resumed session recomputes the remaining poses from it.
Angles are radians; degrees appear only at the CLI boundary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from gonio.errors import DataError

#: Version of the dict layout written by :meth:`Plan.to_dict`.
PLAN_FORMAT = 1


def _as_float_tuple(values, name: str, source: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in np.atleast_1d(np.asarray(values, dtype=np.float64)))
    except (TypeError, ValueError):
        raise DataError(f"{source}: {name} = {values!r}: must be numbers") from None
    return out


#: Most frames averaged per exposure a plan may ask for: averaging lowers σ only as 1/√frames (1000 frames: 3 %
#: of one frame's σ), while a typo of 10⁸ would keep the rig capturing for years
MAX_FRAMES = 1000

#: Longest settle or readout time a plan may ask for, seconds (an hour per pose; ``--warmup-wait`` has the same bound).
MAX_WAIT_S = 3600.0


@dataclass(frozen=True)
class CaptureSettings:
    """How each pose is captured.

    Attributes
    ----------
    exposures : tuple of float
        Exposure bracket, seconds (one HDR frame set per pose uses all of them). With
        ``auto_exposure`` the *expected* bracket: the lab-time estimate uses it, the exposure ladder
        (whose dark frames the session measures) is built around it.
    frames : int
        Frames averaged per exposure (with ``auto_exposure`` the expected frames: automatic exposure
        averages more only where a sample tile is too small or too dim for the target SNR in one frame,
        :func:`gonio.pipeline.exposure.plan_bracket`).
    gain : float
        Analogue gain (linear, 1 = unity).
    readout : float
        Per-frame overhead (readout + transfer), seconds.
    settle : float
        Time to wait after a move before capturing (vibration settling), seconds; at most
        :data:`MAX_WAIT_S` (as ``readout``), like ``--warmup-wait``.
    auto_exposure : bool
        Choose the bracket per pose from its metering frame (:func:`gonio.pipeline.exposure.plan_bracket`
        on the exposure ladder; more frames where the SNR is below target) instead of capturing the
        fixed bracket. On by default (benchmarks/report/REPORT.md, capture table: no sample lost to
        saturation on a glossy lobe for about the same lab time); ``--exposures``/``--frames`` turn it off.
    """

    exposures: tuple[float, ...] = (0.004, 0.016, 0.064)
    frames: int = 1
    gain: float = 1.0
    readout: float = 0.05
    settle: float = 0.3
    auto_exposure: bool = True

    def __post_init__(self):
        exps = _as_float_tuple(self.exposures, "capture.exposures", "plan")
        object.__setattr__(self, "exposures", exps)
        if not exps or not all(math.isfinite(e) and e > 0 for e in exps):
            raise DataError(f"plan: capture.exposures = {list(exps)!r}: must be positive seconds")
        if int(self.frames) != self.frames or not 1 <= self.frames <= MAX_FRAMES:
            raise DataError(f"plan: capture.frames = {self.frames!r}: must be an integer in [1, {MAX_FRAMES}]")
        object.__setattr__(self, "frames", int(self.frames))
        for name in ("gain", "readout", "settle"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0 or (name == "gain" and v == 0):
                raise DataError(f"plan: capture.{name} = {v!r}: must be finite and positive")
            if name != "gain" and v > MAX_WAIT_S:  # 1e308 overflowed the lab-time estimate; 1e6 s never ends
                raise DataError(f"plan: capture.{name} = {v!r}: must be seconds in [0, {MAX_WAIT_S:g}]")
            object.__setattr__(self, name, v)
        if not isinstance(self.auto_exposure, (bool, np.bool_)):
            raise DataError(f"plan: capture.auto_exposure = {self.auto_exposure!r}: must be true or false")
        object.__setattr__(self, "auto_exposure", bool(self.auto_exposure))

    def capture_time(self) -> float:
        """Expected seconds capturing one pose: a metering frame + ``frames · Σ (exposure + readout)``
        (:func:`gonio.plan.labtime.pose_capture_time`, the runner's cost model)."""
        from gonio.plan.labtime import pose_capture_time

        return pose_capture_time(self)

    def pose_time(self) -> float:
        """Expected fixed seconds per pose, independent of the order: settle + capture."""
        return self.settle + self.capture_time()

    def to_dict(self) -> dict[str, Any]:
        return {"exposures": list(self.exposures), "frames": self.frames, "gain": self.gain,
                "readout": self.readout, "settle": self.settle, "auto_exposure": self.auto_exposure}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "plan") -> "CaptureSettings":
        if not isinstance(d, Mapping):
            raise DataError(f"{source}: capture = {d!r}: must be a table")
        unknown = sorted(set(d) - {"exposures", "frames", "gain", "readout", "settle", "auto_exposure"})
        if unknown:
            raise DataError(f"{source}: capture.{unknown[0]}: unknown field")
        try:
            return cls(**{"auto_exposure": False, **dict(d)})  # stored before auto exposure: a fixed bracket
        except DataError as exc:
            raise DataError(f"{source}: {str(exc).removeprefix('plan: ')}") from None


@dataclass(frozen=True)
class Plan:
    """An ordered list of poses and everything needed to measure and describe them.

    Attributes
    ----------
    poses : ndarray (N, 4)
        ``(θi, φi, θo, φo)`` in radians, in measurement order. Pose *k* of the session is row *k*.
    capture : CaptureSettings
        Exposure bracket, frames averaged, gain, settle time.
    generator : str
        Name of the generator that made the poses (``grid``, ``isotropic``, ...).
    params : dict
        The generator's parameters (angles in radians), JSON-able.
    dropped : tuple of dict
        Poses the rig cannot reach: ``{"pose": [θi, φi, θo, φo], "reason": str}``.
    joints : ndarray (N, J) or None
        Joint angles of each pose (radians) if known (from the rig's kinematics).
    order : str
        How the poses were ordered (``generated``, ``raster``, ``optimized``).
    """

    poses: np.ndarray
    capture: CaptureSettings = field(default_factory=CaptureSettings)
    generator: str = "custom"
    params: Mapping[str, Any] = field(default_factory=dict)
    dropped: tuple[Mapping[str, Any], ...] = ()
    joints: np.ndarray | None = None
    order: str = "generated"

    def __post_init__(self):
        poses = np.array(self.poses, dtype=np.float64)
        if poses.size == 0:
            poses = poses.reshape(0, 4)
        if poses.ndim != 2 or poses.shape[1] != 4:
            raise DataError(f"plan: poses have shape {poses.shape}, expected (N, 4)")
        if not np.all(np.isfinite(poses)):
            raise DataError("plan: poses contain non-finite angles")
        poses.setflags(write=False)
        object.__setattr__(self, "poses", poses)
        if self.joints is not None:
            j = np.array(self.joints, dtype=np.float64)
            if j.ndim != 2 or j.shape[0] != poses.shape[0]:
                raise DataError(f"plan: joints have shape {j.shape}, expected ({poses.shape[0]}, J)")
            j.setflags(write=False)
            object.__setattr__(self, "joints", j)
        object.__setattr__(self, "params", dict(self.params))
        object.__setattr__(self, "dropped", tuple(dict(d) for d in self.dropped))

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def n_dropped(self) -> int:
        """Number of generated poses the rig cannot reach."""
        return len(self.dropped)

    def dropped_reasons(self) -> dict[str, int]:
        """Count of dropped poses per reason."""
        out: dict[str, int] = {}
        for d in self.dropped:
            out[d["reason"]] = out.get(d["reason"], 0) + 1
        return out

    def dropped_summary(self) -> str:
        """The dropped poses by reason, e.g. ``"6 collision, 12 duplicate, 34 horizon"`` (empty if none)."""
        return ", ".join(f"{n} {r}" for r, n in sorted(self.dropped_reasons().items()))

    def reordered(self, order: Sequence[int], how: str) -> "Plan":
        """The same plan with its poses (and joints) permuted by ``order``."""
        order = np.asarray(order, dtype=np.int64)
        if sorted(order.tolist()) != list(range(len(self))):
            raise ValueError("reordered: order must be a permutation of the pose indices")
        joints = None if self.joints is None else self.joints[order]
        return replace(self, poses=self.poses[order], joints=joints, order=how)

    # -- JSON round trip ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict; floats are written with ``repr`` so they round-trip exactly."""
        return {
            "format": PLAN_FORMAT,
            "units": "rad",
            "generator": self.generator,
            "params": _jsonable(self.params),
            "capture": self.capture.to_dict(),
            "order": self.order,
            "n_poses": len(self),
            "poses": self.poses.tolist(),
            "joints": None if self.joints is None else self.joints.tolist(),
            "dropped": [_jsonable(d) for d in self.dropped],
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "plan") -> "Plan":
        """Inverse of :meth:`to_dict`; :class:`DataError` naming ``source`` and the field on bad input."""
        if not isinstance(d, Mapping):
            raise DataError(f"{source}: a plan must be a JSON object, got {type(d).__name__}")
        if d.get("format") != PLAN_FORMAT:
            what = ("; it is not a plan (no 'poses'; a fit result, a report?)" if "poses" not in d else
                    "; written by a newer gonio?" if isinstance(d.get("format"), int) and d["format"] > PLAN_FORMAT
                    else "")
            raise DataError(f"{source}: format = {d.get('format')!r}: expected {PLAN_FORMAT}{what}")
        if d.get("units", "rad") != "rad":
            raise DataError(f"{source}: units = {d.get('units')!r}: expected 'rad'")
        for key in ("poses", "generator"):
            if key not in d:
                raise DataError(f"{source}: missing field {key!r}")
        try:
            plan = cls(
                poses=np.asarray(d["poses"], dtype=np.float64),
                capture=CaptureSettings.from_dict(d.get("capture", {}), source),
                generator=str(d["generator"]),
                params=dict(d.get("params", {})),
                dropped=tuple(d.get("dropped", ())),
                joints=None if d.get("joints") is None else np.asarray(d["joints"], dtype=np.float64),
                order=str(d.get("order", "generated")),
            )
        except (TypeError, ValueError) as exc:
            raise DataError(f"{source}: not a valid plan ({exc})") from None
        except DataError as exc:
            msg = str(exc)
            raise DataError(msg if msg.startswith(source) else f"{source}: {msg.removeprefix('plan: ')}") from None
        if "n_poses" in d and d["n_poses"] != len(plan):
            raise DataError(f"{source}: n_poses = {d['n_poses']!r} but {len(plan)} poses are listed")
        return plan


def _jsonable(obj: Any) -> Any:
    """Plain JSON types from numpy scalars/arrays, tuples and nested mappings."""
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
