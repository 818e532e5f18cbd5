"""The *as-built* simulated rig: the geometry the simulator really renders with, not the declared one.

No real rig is built as its rig file says. :class:`AsBuilt` holds a rig's assembly errors
(:class:`gonio.rig.chain.ChainErrors`: servo zero offsets, axis tilts and non-orthogonality, axes
missing the sample centre, light/camera distances, the light's offset from its arm's plane, the
camera's mounting rotation on its arm, sample height), drawn from a seed (:meth:`AsBuilt.from_seed`,
uniform within :data:`TOLERANCES`, a typical hand-assembled rig) or read from a TOML file
(:meth:`AsBuilt.from_file`, same fields as :meth:`ChainErrors.to_dict`). The host only ever sees the declared rig file; :class:`sim.rig.SimRig`
places the camera and the light with :meth:`AsBuilt.camera_pose` / :meth:`AsBuilt.light_position`
(the hook), so every frame is rendered on the as-built rig. ``AsBuilt.perfect(rig)`` (no errors) gives
bit for bit the declared geometry.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from gonio.errors import ConfigError
from gonio.rig.chain import ARM_FIELDS, CAMERA_FIELDS, TURNTABLE_FIELDS, ChainErrors, chain_forward, true_directions

__all__ = ["AsBuilt", "TOLERANCES", "observe", "parse_as_built", "render_observations"]

#: Half-widths of the uniform assembly errors of :meth:`AsBuilt.from_seed` (issue 15's "realistic" rig).
TOLERANCES = {
    "d_az_deg": 3.0, "d_el_deg": 3.0,            # servo horn zero offsets
    "tilt_x_deg": 0.5, "tilt_y_deg": 0.5, "nonorth_deg": 0.5,   # axis tilts / non-orthogonality
    "axis_x_mm": 3.0, "axis_y_mm": 3.0, "arc_x_mm": 3.0, "arc_z_mm": 3.0,  # axes missing the sample centre
    "d_radius_mm": 5.0,                          # light / camera distance
    "lateral_mm": 3.0,                           # device offset from its arm's plane
    "mount_x_deg": 1.0, "mount_y_deg": 1.0, "mount_z_deg": 1.0,  # camera mounting rotation on its bracket
    "sample_height_mm": 1.0,
}


class AsBuilt:
    """A declared rig plus its assembly errors; see the module docstring."""

    def __init__(self, rig, errors: ChainErrors | None = None, *, source: str = "perfect"):
        self.rig = rig
        self.errors = errors or ChainErrors()
        self.source = source

    @classmethod
    def perfect(cls, rig) -> "AsBuilt":
        return cls(rig)

    @classmethod
    def from_seed(cls, rig, seed: int) -> "AsBuilt":
        """Errors uniform in ±:data:`TOLERANCES` from ``numpy.random.default_rng([seed, 15])``."""
        rng = np.random.default_rng([int(seed), 15])

        def draw(fields):
            return {k: float(rng.uniform(-TOLERANCES[k], TOLERANCES[k])) for k in fields}

        light, camera = draw(ARM_FIELDS), draw(CAMERA_FIELDS)
        turntable = draw(TURNTABLE_FIELDS) if rig.layout == "turntable" else {k: 0.0 for k in TURNTABLE_FIELDS}
        h = float(rng.uniform(-TOLERANCES["sample_height_mm"], TOLERANCES["sample_height_mm"]))
        return cls(rig, ChainErrors(light, camera, turntable, h), source=f"seed {int(seed)}")

    @classmethod
    def from_file(cls, rig, path) -> "AsBuilt":
        """Errors from a TOML file (``[light]``, ``[camera]``, ``[turntable]`` tables, ``sample_height_mm``)."""
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"{p}: cannot read the as-built geometry: {exc.strerror or exc}") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{p}: not a TOML file: {exc}") from None
        return cls(rig, ChainErrors.from_dict(data, source=str(p)), source=str(p))

    def to_dict(self) -> dict:
        """What the session manifest's ``sim.as_built`` records (rebuilt by :meth:`from_dict`)."""
        return {"source": self.source, **self.errors.to_dict()}

    @classmethod
    def from_dict(cls, rig, d, source: str = "sim.as_built") -> "AsBuilt":
        if not isinstance(d, dict):
            raise ConfigError(f"{source}: expected the as-built errors (a table), got {str(d)[:40]!r}")
        d = dict(d)
        src = d.pop("source", "manifest")
        return cls(rig, ChainErrors.from_dict(d, source=source), source=str(src))

    # -- the hook sim/rig.py calls per frame --------------------------------------------------------
    def light_position(self, joints) -> np.ndarray:
        """True light position (sample frame, m)."""
        return chain_forward(self.rig, self.errors, joints)[0]

    def camera_pose(self, joints):
        """True ``(position, R)`` of the camera, :meth:`gonio.rig.kinematics.Rig.camera_pose`'s convention."""
        _, pc, R = chain_forward(self.rig, self.errors, joints)
        return pc, R

    def directions(self, joints):
        """True unit ``(wi, wo)`` at the sample centre."""
        return true_directions(self.rig, self.errors, joints)


def render_observations(as_built: AsBuilt, plan: dict, seed: int = 0, *, joint_deg: float = 0.02, config=None):
    """Calibration observations from frames the simulated camera renders on the as-built rig, detected by
    gonio's own code (:func:`gonio.session.geocal_observe.observe_pose`: the ChArUco pose with its
    covariance; the light's highlight in the 80 mm glossy black tile on the stage, sub-pixel, with its
    covariance). The arms stand ``joint_deg`` (servo noise, backlash; Gaussian) off the commanded joints,
    which are what the observations record. Returns ``(cams, highs, refused)``: every frame with a board
    pose is a camera observation; ``refused`` lists ``(kind, index, reason)`` of poses that gave none."""
    from gonio.pipeline.target import CameraPose
    from gonio.session.geocal_observe import calibration_layout, observe_pose
    from sim.rig import SimRig, SimRigConfig

    rig = as_built.rig
    cfg = config or SimRigConfig(seed=seed)
    from dataclasses import replace

    cfg = replace(cfg, as_built=as_built.to_dict(), tile=cfg.tile or {})
    sim = SimRig(rig, config=cfg, layout=calibration_layout())
    cam = sim.sim_camera
    cam._light_output = None  # no controller running: the light is simply on
    rng = np.random.default_rng([int(seed), 1517])
    cams, highs, refused = [], [], []
    for kind in ("camera", "highlight"):
        for k, j in enumerate(np.asarray(plan[kind], dtype=np.float64)):
            actual = j + np.radians(rng.normal(0.0, joint_deg, j.shape))
            pc, R = as_built.camera_pose(actual)
            cam.set_pose(CameraPose(R, -R @ pc))
            cam.set_light(as_built.light_position(actual), on=True, output=1.0)
            cam.reseed([int(seed), k, 1516 if kind == "camera" else 1518])
            c, h, why = observe_pose(cam, sim.calibration, sim.layout, j, highlight=kind == "highlight",
                                     min_exposure=sim.sensor.min_exposure)
            if c is not None:
                cams.append(c)
            if h is not None:
                highs.append(h)
            elif why:
                refused.append((kind, k, why))
    return cams, highs, refused


def observe(as_built: AsBuilt, plan: dict, seed: int = 0, *, pose_mm: float = 0.2, pose_deg: float = 0.02,
            highlight_px: float = 0.2, focal_px: float = 380.0, joint_deg: float = 0.02, render: bool = False):
    """Calibration observations on the as-built rig for ``plan`` (:func:`gonio.rig.geocal.calibration_plan`).

    ``render=False`` (cheap, for tests): *geometric* observations — the camera's ChArUco pose with
    Gaussian noise (``pose_mm``, ``pose_deg`` per axis) and the light's mirror image projected with
    ``highlight_px`` of noise at ``focal_px``, no frames, no covariances; the arms stand ``joint_deg``
    off the commanded joints. ``render=True``: :func:`render_observations` (rendered frames, detected by
    gonio's pipeline; the board poses of highlight frames are camera observations too)."""
    from gonio.rig.geocal import CameraObservation, HighlightObservation

    if render:
        cams, highs, _ = render_observations(as_built, plan, seed, joint_deg=joint_deg)
        return cams, highs
    rng = np.random.default_rng([int(seed), 1515])
    rig = as_built.rig

    def noisy_pose(j):
        actual = j + np.radians(rng.normal(0.0, joint_deg, j.shape))
        _, pc, R = chain_forward(rig, as_built.errors, actual)
        rv = np.radians(rng.normal(0.0, pose_deg, 3))
        from gonio.rig.chain import _rx, _ry, _rz
        dR = _rx(np.asarray(rv[0])) @ _ry(np.asarray(rv[1])) @ _rz(np.asarray(rv[2]))
        return actual, pc + rng.normal(0.0, pose_mm * 1e-3, 3), pc, R, dR @ R

    cams, highs = [], []
    for j in plan["camera"]:
        _, obs_p, _, _, obs_R = noisy_pose(j)
        cams.append(CameraObservation(np.array(j), obs_p, obs_R))
    for j in plan["highlight"]:
        actual, obs_p, pc, R, obs_R = noisy_pose(j)
        pl = chain_forward(rig, as_built.errors, actual)[0] * np.array([1.0, 1.0, -1.0])
        v = R @ (pl - pc)
        xy = v[:2] / v[2] + rng.normal(0.0, highlight_px / focal_px, 2)
        highs.append(HighlightObservation(np.array(j), xy, obs_p, obs_R))
    return cams, highs


def parse_as_built(rig, spec) -> AsBuilt:
    """``--sim-as-built`` value: an integer seed, or a TOML file of errors; ``None``/empty: perfect."""
    if spec is None or spec == "":
        return AsBuilt.perfect(rig)
    text = str(spec).strip()
    try:
        seed = int(text)
    except ValueError:
        return AsBuilt.from_file(rig, text)
    if seed < 0:
        raise ConfigError(f"--sim-as-built {text}: expected a seed >= 0 or a TOML file of assembly errors")
    return AsBuilt.from_seed(rig, seed)
