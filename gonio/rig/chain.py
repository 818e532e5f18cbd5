"""Kinematic chain of a gonio rig with its assembly errors: where the light and the camera really are.

The declared rig (:class:`gonio.rig.kinematics.Rig`) assumes a perfect build: both arms' azimuth axes
are the sample normal through the sample centre, the elevation axes are orthogonal to them and meet
them at the sample centre, the servo zeros are exact, the light and the camera sit on their arcs at
exactly the declared radii. :class:`ChainErrors` names every deviation from that, and
:func:`chain_forward` gives the true light position and camera pose for joint angles ``(..., 4)``.
It is used in both directions: the simulator's *as-built* rig renders with it (``sim/as_built.py``),
and the geometric calibration (:mod:`gonio.rig.geocal`) estimates its parameters.

Model (one arm; a Denavit–Hartenberg-like product of exponentials, Hayati & Mirmirani 1985's
"modified" parameters for near-parallel/near-orthogonal axes; Lynch & Park, *Modern Robotics*, §4.1):

    Q   = A(tx, ty) · Rz(az + δaz) · Rx(β) · Ry(el + δel)
    c   = (ox, oy, 0) + A(tx, ty) · Rz(az + δaz) · (ex, 0, ez)
    p   = c + Q · (0, lat, r + δr)                 (device position, lab frame)
    camera: looks along −Q·ẑ (at the arc centre), its x axis along Q·ŷ, then turned by its mounting
            rotation M = Rx(mx)·Ry(my)·Rz(mz) about its own axes (R = M · R_arm; rows = camera axes)

``A(tx, ty) = Rx(tx)·Ry(ty)`` tilts the azimuth axis, ``β`` is the elevation axis's non-orthogonality,
``(ox, oy)`` is where the azimuth axis pierces the sample plane, ``(ex, ez)`` the arc centre's offset
from the azimuth axis in the arm's plane, ``lat`` the device's offset from the arm's plane (along the
elevation axis). The turntable layout turns the lab into the sample frame by
``(A(tx_s, ty_s) · Rz(sample_az + δs))ᵀ``. The sample surface is ``dh`` above the declared centre;
every position is finally expressed relative to it. ``dh`` and a common ``ez`` of both arms have
the same effect (only ``ez − dh`` is observable): :data:`ARM_FIELDS` keeps ``ez`` per arm and the
calibration reports ``dh`` as not identified.

The camera's mounting rotation on its arm (:data:`CAMERA_FIELDS`: how its bracket holds it) does not move
it, so it changes no direction wi/wo; it turns the image, i.e. the board poses and where the light's
highlight appears, and the calibration must estimate it to use them. The light, a point source, has none.

Units in :class:`ChainErrors`: angles in degrees, lengths in millimetres (what a lab types in a TOML).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gonio.errors import ConfigError

__all__ = ["ARM_FIELDS", "CAMERA_FIELDS", "TURNTABLE_FIELDS", "ChainErrors", "chain_forward", "true_directions", "angle_between_deg"]

#: Per-arm error fields: name → (unit, description).
ARM_FIELDS = {
    "d_az_deg": ("deg", "azimuth servo zero-offset error"),
    "d_el_deg": ("deg", "elevation servo zero-offset error"),
    "tilt_x_deg": ("deg", "azimuth axis tilt about x"),
    "tilt_y_deg": ("deg", "azimuth axis tilt about y"),
    "nonorth_deg": ("deg", "elevation axis non-orthogonality to the azimuth axis"),
    "axis_x_mm": ("mm", "azimuth axis miss of the sample centre, x"),
    "axis_y_mm": ("mm", "azimuth axis miss of the sample centre, y"),
    "arc_x_mm": ("mm", "arc centre offset from the azimuth axis, in the arm plane"),
    "arc_z_mm": ("mm", "arc centre height above the sample surface"),
    "d_radius_mm": ("mm", "device distance error from the arc centre"),
    "lateral_mm": ("mm", "device offset from the arm plane (along the elevation axis)"),
}
#: Camera arm error fields: the arm's, plus the camera's mounting rotation about its own axes.
CAMERA_FIELDS = {
    **ARM_FIELDS,
    "mount_x_deg": ("deg", "camera mounting rotation about its x axis (image rows tilt)"),
    "mount_y_deg": ("deg", "camera mounting rotation about its y axis (image columns pan)"),
    "mount_z_deg": ("deg", "camera mounting rotation about its optical axis (image roll)"),
}
#: Turntable error fields (turntable layout only).
TURNTABLE_FIELDS = {
    "d_az_deg": ("deg", "turntable zero-offset error"),
    "tilt_x_deg": ("deg", "turntable axis tilt about x"),
    "tilt_y_deg": ("deg", "turntable axis tilt about y"),
}


def _zero_arm() -> dict:
    return {k: 0.0 for k in ARM_FIELDS}


def _zero_camera() -> dict:
    return {k: 0.0 for k in CAMERA_FIELDS}


@dataclass
class ChainErrors:
    """Assembly errors of a rig (all zero: the declared, perfect rig). See the module docstring."""

    light: dict = field(default_factory=_zero_arm)
    camera: dict = field(default_factory=_zero_camera)
    turntable: dict = field(default_factory=lambda: {k: 0.0 for k in TURNTABLE_FIELDS})
    sample_height_mm: float = 0.0

    def folded(self) -> "ChainErrors":
        """The same rig with the sample height ``dh`` folded into both arcs' ``arc_z_mm`` (what images of the
        sample plane can determine). Lowering the arc centre along its tilted azimuth axis ``A·ẑ`` instead of
        the sample along ``ẑ`` also moves it sideways by ``dh (A·ẑ − ẑ)``, which the axis's miss of the centre
        takes back: ``axis_x_mm += dh sin ty``, ``axis_y_mm −= dh sin tx cos ty`` (``A·ẑ`` of
        :func:`chain_forward`'s model); what is left is ``dh (1 − cos)`` of the tilts, < 1e-4 mm. (The
        turntable layout's own tilt is left out: its arms stand in the lab frame.)"""
        light, camera = dict(self.light), dict(self.camera)
        dh = self.sample_height_mm
        for arm in (light, camera):
            arm["arc_z_mm"] -= dh
            tx, ty = math.radians(arm["tilt_x_deg"]), math.radians(arm["tilt_y_deg"])
            arm["axis_x_mm"] += dh * math.sin(ty)
            arm["axis_y_mm"] -= dh * math.sin(tx) * math.cos(ty)
        return ChainErrors(light, camera, dict(self.turntable), 0.0)

    # -- flat parameter vector (the calibration's unknowns) ---------------------------------------
    def names(self) -> list[str]:
        return ([f"light.{k}" for k in ARM_FIELDS] + [f"camera.{k}" for k in CAMERA_FIELDS]
                + [f"turntable.{k}" for k in TURNTABLE_FIELDS] + ["sample_height_mm"])

    def vector(self) -> np.ndarray:
        return np.array([self.light[k] for k in ARM_FIELDS] + [self.camera[k] for k in CAMERA_FIELDS]
                        + [self.turntable[k] for k in TURNTABLE_FIELDS] + [self.sample_height_mm], dtype=np.float64)

    @classmethod
    def from_vector(cls, v) -> "ChainErrors":
        v = [float(x) for x in np.asarray(v, dtype=np.float64).ravel()]
        na, nc, nt = len(ARM_FIELDS), len(CAMERA_FIELDS), len(TURNTABLE_FIELDS)
        return cls(dict(zip(ARM_FIELDS, v[:na])), dict(zip(CAMERA_FIELDS, v[na:na + nc])),
                   dict(zip(TURNTABLE_FIELDS, v[na + nc:na + nc + nt])), v[na + nc + nt])

    @classmethod
    def from_vectors(cls, V) -> "ChainErrors":
        """A batch of K parameter vectors ``V`` (K, P) (:meth:`vector`'s order) as one ``ChainErrors`` whose
        fields are (K, 1) arrays: :func:`chain_forward` then gives all K chains at N joints at once, (K, N, ...)."""
        V = np.asarray(V, dtype=np.float64)
        cols = [V[:, i, None] for i in range(V.shape[1])]
        na, nc, nt = len(ARM_FIELDS), len(CAMERA_FIELDS), len(TURNTABLE_FIELDS)
        return cls(dict(zip(ARM_FIELDS, cols[:na])), dict(zip(CAMERA_FIELDS, cols[na:na + nc])),
                   dict(zip(TURNTABLE_FIELDS, cols[na + nc:na + nc + nt])), cols[na + nc + nt])

    def to_dict(self) -> dict:
        return {"light": dict(self.light), "camera": dict(self.camera), "turntable": dict(self.turntable),
                "sample_height_mm": float(self.sample_height_mm)}

    @classmethod
    def from_dict(cls, d, source: str = "as-built geometry") -> "ChainErrors":
        """From :meth:`to_dict`'s shape; every value checked (ConfigError naming ``source`` and the field).
        Missing fields are 0 (perfect); unknown fields are refused (a typo must not pass as perfect)."""
        if not isinstance(d, dict):
            raise ConfigError(f"{source}: expected a table of assembly errors, got {str(d)[:40]!r}")
        out = cls()
        for key, value in d.items():
            if key == "sample_height_mm":
                out.sample_height_mm = _number(source, key, value, 20.0)
                continue
            fields = {"light": ARM_FIELDS, "camera": CAMERA_FIELDS, "turntable": TURNTABLE_FIELDS}.get(key)
            if fields is None:
                raise ConfigError(f"{source}: unknown section {key!r} (expected light, camera, turntable, sample_height_mm)")
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: {key} = {str(value)[:40]!r}: expected a table")
            target = getattr(out, key)
            for k, x in value.items():
                if k not in fields:
                    raise ConfigError(f"{source}: {key}.{k}: unknown field (expected one of {', '.join(fields)})")
                # bounds: far beyond any assembly error, still small-angle / small-offset
                target[k] = _number(source, f"{key}.{k}", x, 20.0 if k.endswith("_deg") else 50.0)
        return out


def _number(source, key, value, bound) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and abs(value) <= bound
    if not ok:
        raise ConfigError(f"{source}: {key} = {str(value)[:40]}: expected a number in [-{bound:g}, {bound:g}]")
    return float(value)


# -- rotations (batched) ---------------------------------------------------------------------------
def _rot(a, axis: int):
    """Rotations by angles ``a`` (any shape) about coordinate axis ``axis`` (0: x, 1: y, 2: z): (..., 3, 3),
    the right-handed matrices R_x, R_y, R_z, written element by element into one array (nine small
    ``np.stack`` calls each, as before, were most of the cost of the calibration's residuals)."""
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(np.shape(c) + (3, 3))
    i, j = (1, 2) if axis == 0 else (2, 0) if axis == 1 else (0, 1)  # the plane the rotation turns
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def _rx(a):
    return _rot(a, 0)


def _ry(a):
    return _rot(a, 1)


def _rz(a):
    return _rot(a, 2)


def _arm(e: dict, az, el, radius_m: float):
    """Device position (lab frame, m) and orientation ``Q`` (..., 3, 3) of one arm (module docstring). The
    fields of ``e`` are numbers, or arrays (a batch of parameter vectors, :meth:`ChainErrors.from_vectors`)
    that broadcast against ``az`` and ``el``: the same products and sums either way. A batch computes each
    distinct arm once (:func:`_distinct_rows`)."""
    one = isinstance(e["d_az_deg"], float)  # one chain: Python numbers (NumPy's per-call cost on scalars avoided)
    if not one and np.ndim(az) <= 1 and np.ndim(el) <= 1:
        rows = _distinct_rows(e)
        if rows is not None:
            rows, back = rows
            p, Q = _arm({k: e[k][rows] for k in ARM_FIELDS}, az, el, radius_m)
            return p[back], Q[back]
    d, vec = (math.radians, _vec3) if one else (np.radians, _vecs)
    A = _rx(np.asarray(d(e["tilt_x_deg"]))) @ _ry(np.asarray(d(e["tilt_y_deg"])))
    Raz = A @ _rz(az + d(e["d_az_deg"]))
    nonorth = d(e["nonorth_deg"])
    N = np.full_like(az, nonorth) if one else np.broadcast_to(nonorth, np.broadcast_shapes(np.shape(az), np.shape(nonorth)))
    Q = Raz @ _rx(N) @ _ry(el + d(e["d_el_deg"]))
    arc = vec(e["arc_x_mm"], 0.0, e["arc_z_mm"]) * 1e-3
    dev = vec(0.0, e["lateral_mm"] * 1e-3, radius_m + e["d_radius_mm"] * 1e-3)
    c = vec(e["axis_x_mm"], e["axis_y_mm"], 0.0) * 1e-3 + (Raz @ arc if one else (Raz @ arc[..., None])[..., 0])
    return c + (Q @ dev if one else (Q @ dev[..., None])[..., 0]), Q


def _distinct_rows(e: dict):
    """``(rows, back)`` for a batch of arm fields (each (K, 1)) in which rows repeat the first, bit for bit — a
    Jacobian's columns for the other arm's parameters, or for the camera's mounting rotation, leave this arm as
    its first row has it — the rows to compute (the first and those that differ from it) and, for every row,
    which of them it is; None if no row repeats the first."""
    try:
        bits = np.stack([np.asarray(e[k], dtype=np.float64).reshape(-1) for k in ARM_FIELDS], axis=1).view(np.int64)
    except ValueError:  # fields of different shapes: no rows to compare
        return None
    differ = np.any(bits != bits[0], axis=1)
    if differ.all() or differ.sum() == len(bits) - 1:
        return None
    rows = np.concatenate([[0], np.flatnonzero(differ)])
    back = np.zeros(len(bits), dtype=np.intp)
    back[rows] = np.arange(len(rows))
    return rows, back


def _vec3(x, y, z) -> np.ndarray:
    """The vector ``(x, y, z)`` (3,) of numbers."""
    return np.array([x, y, z])


def _vecs(x, y, z) -> np.ndarray:
    """The vectors ``(x, y, z)`` (..., 3) of broadcasting numbers or arrays."""
    x, y, z = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, y, z)))
    return np.stack([x, y, z], axis=-1)


def chain_forward(rig, errors: ChainErrors, joints):
    """True light position, camera position and camera rotation in the sample frame for joints ``(..., 4)``
    of ``rig``'s layout (``gonio.rig.kinematics.Rig``): ``(light (..., 3), cam (..., 3), R (..., 3, 3))``,
    ``R`` in :meth:`gonio.rig.kinematics.Rig.camera_pose`'s convention (rows: camera x, y, z in sample
    coordinates). All-zero ``errors`` reproduce ``rig.light_position`` / ``rig.camera_pose`` exactly.

    ``errors`` may hold a batch of K parameter vectors (:meth:`ChainErrors.from_vectors`: every field a (K, 1)
    array) for joints (N, 4): the results are then (K, N, 3) and (K, N, 3, 3), row k the same numbers, bit for
    bit, as for the k-th vector alone (what the calibration's all-columns-at-once Jacobian relies on)."""
    j = rig.as_array(joints)
    if rig.layout == "turntable":
        s = j[..., 0]
        laz, lel, caz, cel = np.full_like(s, rig.light_azimuth), j[..., 1], j[..., 2], j[..., 3]
    else:
        s = None
        laz, lel, caz, cel = j[..., 0], j[..., 1], j[..., 2], j[..., 3]
    pl, _ = _arm(errors.light, laz, lel, rig.light_radius)
    pc, Q = _arm(errors.camera, caz, cel, rig.camera_radius)
    # camera axes: x = arm's azimuth tangent (Q·ŷ), z = toward the arc centre (−Q·ẑ), y = z × x
    x, z = Q[..., :, 1], -Q[..., :, 2]
    R = np.stack([x, np.cross(z, x), z], axis=-2)
    m = errors.camera
    mx, my, mz = m.get("mount_x_deg", 0.0), m.get("mount_y_deg", 0.0), m.get("mount_z_deg", 0.0)
    one = isinstance(mx, float) and isinstance(my, float) and isinstance(mz, float)
    turned = (mx or my or mz) if one else np.broadcast_to((np.asarray(mx) != 0) | (np.asarray(my) != 0)
                                                         | (np.asarray(mz) != 0), R.shape[:-2])
    if turned if one else np.any(turned):
        d = math.radians if one else np.radians
        M = _rx(np.asarray(d(mx))) @ _ry(np.asarray(d(my))) @ _rz(np.asarray(d(mz)))
        if one or np.all(turned):
            R = M @ R
        else:  # a batch whose mounting rotations are zero in some rows: those keep R untouched (as alone)
            R = R.copy()
            R[turned] = np.broadcast_to(M, R.shape)[turned] @ R[turned]
    if s is not None:  # lab → sample frame: the turntable's rotation, inverted
        t = errors.turntable
        d = math.radians if isinstance(t["d_az_deg"], float) else np.radians
        T = _rx(np.asarray(d(t["tilt_x_deg"]))) @ _ry(np.asarray(d(t["tilt_y_deg"]))) @ _rz(s + d(t["d_az_deg"]))
        Tt = np.swapaxes(T, -1, -2)
        pl = (Tt @ pl[..., None])[..., 0]
        pc = (Tt @ pc[..., None])[..., 0]
        R = R @ T
    dh = errors.sample_height_mm * 1e-3
    h = _vec3(0.0, 0.0, dh) if isinstance(dh, float) else _vecs(0.0, 0.0, dh)
    return pl - h, pc - h, R


def true_directions(rig, errors: ChainErrors, joints):
    """Unit ``(wi, wo)`` from the sample centre to the true light and camera positions (:func:`chain_forward`)."""
    pl, pc, _ = chain_forward(rig, errors, joints)
    return pl / np.linalg.norm(pl, axis=-1, keepdims=True), pc / np.linalg.norm(pc, axis=-1, keepdims=True)


def angle_between_deg(a, b) -> np.ndarray:
    """Angle (degrees) between unit vectors ``a`` and ``b`` (..., 3), by atan2 of |a×b| and a·b (accurate
    for small angles, unlike arccos; Kahan, "How futile are mindless assessments of roundoff", 2006 §12)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
