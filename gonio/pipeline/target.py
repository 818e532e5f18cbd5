"""What the camera looks at and how it sees it: the target layout, the camera model and its pose.

Shared by the renderer (``sim.camera``) and the pipeline, so both agree on where the ChArUco board,
the sample patch and the white reference patch are.

Frames
------
*Sample frame* (= world frame of the simulation, docs/architecture.md §3): origin at the sample centre,
z = sample normal, x = reference direction. *Board frame* (OpenCV's ChArUco object points):
origin at the board's top-left corner, x along the image columns, y along the rows, z into the
board. The board is mounted with its centre on the sample centre, so
``board = (x_s + W/2, H/2 − y_s, −z_s)`` — a rotation by π about x plus a translation.
*Camera frame* (OpenCV pinhole): x right, y down, z forward; ``X_cam = R X_world + t``.
*Mounted sample frame*: a sample that does not lie in the board plane (a tilted or raised mount,
:class:`SampleMount`) has its own local frame, ``X_world = M X_patch`` (M 4×4 affine); its normal is
M's inverse-transpose applied to z (lecture notes 000, "Note on normals and spaces"), its x axis
M·x made orthogonal to the normal. A flat mount (M = I) makes it the sample frame itself. The
BRDF samples' wi/wo are expressed in this frame (docs/architecture.md §3: z = the sample's normal).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gonio.errors import ConfigError
from gonio.camera_model import CameraCalibration, CameraPose, NoiseModel  # re-exported: the camera model's home
from gonio.geometry import frame_from_normal, transform_normals

__all__ = ["Rect", "CharucoSpec", "SampleMount", "surface_frame", "TargetLayout", "load_target", "NoiseModel",
           "CameraCalibration", "CameraPose"]

#: Rotation board frame -> sample frame (and its own inverse): π about x.
BOARD_TO_SAMPLE_R = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle ``[x0, x1] × [y0, y1]`` in the sample plane (metres, sample frame)."""

    x0: float
    y0: float
    x1: float
    y1: float

    def __post_init__(self):
        if not (np.isfinite([self.x0, self.y0, self.x1, self.y1]).all() and self.x1 > self.x0 and self.y1 > self.y0):
            raise ConfigError.field(None, "rect", (self.x0, self.y0, self.x1, self.y1), "needs x0 < x1 and y0 < y1")

    def contains(self, x, y, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of points ``(x, y)`` at least ``margin`` inside the rectangle."""
        return (x >= self.x0 + margin) & (x <= self.x1 - margin) & (y >= self.y0 + margin) & (y <= self.y1 - margin)

    def corners(self) -> np.ndarray:
        """The 4 corners, shape (4, 3), z = 0."""
        return np.array([[self.x0, self.y0, 0], [self.x1, self.y0, 0], [self.x1, self.y1, 0], [self.x0, self.y1, 0]], float)

    def overlaps(self, other: "Rect") -> bool:
        return not (self.x1 <= other.x0 or other.x1 <= self.x0 or self.y1 <= other.y0 or other.y1 <= self.y0)


#: Largest board side in squares, and smallest marker / square length ratio accepted (OpenCV draws
#: and detects boards within these; beyond them it asserts or raises SystemError).
MAX_SQUARES = 100
MIN_MARKER_RATIO = 0.1


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board (OpenCV 5 ``cv2.aruco.CharucoBoard``), centred on the sample.

    Attributes
    ----------
    squares : (int, int)
        Squares along x (columns) and y (rows).
    square_length, marker_length : float
        Metres.
    dictionary : str
        Name of a ``cv2.aruco`` predefined dictionary, e.g. ``"DICT_5X5_100"``.
    """

    squares: tuple[int, int] = (9, 7)
    square_length: float = 0.03
    marker_length: float = 0.022
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self):
        if not (0 < self.marker_length < self.square_length):
            raise ConfigError.field(None, "charuco.marker_length", self.marker_length, "must be in (0, square_length)")
        if min(self.squares) < 3:
            raise ConfigError.field(None, "charuco.squares", self.squares, "needs at least 3 × 3 squares")
        if max(self.squares) > MAX_SQUARES:
            raise ConfigError.field(None, "charuco.squares", self.squares, f"at most {MAX_SQUARES} squares a side")
        if not (0 < self.square_length <= 10.0):
            raise ConfigError.field(None, "charuco.square_length", self.square_length, "must be in (0, 10] m")
        if self.marker_length < MIN_MARKER_RATIO * self.square_length:
            raise ConfigError.field(None, "charuco.marker_length", self.marker_length,
                                    f"must be at least {MIN_MARKER_RATIO:g} × square_length (a marker the "
                                    "camera can decode)")

    def check_dictionary(self) -> None:
        """The dictionary exists and holds a marker for every white square (⌊columns·rows/2⌋ markers;
        OpenCV's CharucoBoard numbers them from 0): ConfigError otherwise, before OpenCV asserts."""

        d = self.board().getDictionary()
        n_markers, have = self.squares[0] * self.squares[1] // 2, int(d.bytesList.shape[0])
        if n_markers > have:
            raise ConfigError.field(None, "charuco.squares", self.squares,
                                    f"needs {n_markers} markers but {self.dictionary} has {have}")

    @property
    def size(self) -> tuple[float, float]:
        """Board width and height in metres."""
        return self.squares[0] * self.square_length, self.squares[1] * self.square_length

    def board(self):
        """The OpenCV board object (imports cv2)."""
        import cv2

        try:
            dict_id = getattr(cv2.aruco, self.dictionary)
        except AttributeError:
            raise ConfigError.field(None, "charuco.dictionary", self.dictionary, "not a cv2.aruco dictionary") from None
        d = cv2.aruco.getPredefinedDictionary(dict_id)
        return cv2.aruco.CharucoBoard(tuple(self.squares), self.square_length, self.marker_length, d)

    def sample_to_board(self, p) -> np.ndarray:
        """Sample-frame points (..., 3) -> board-frame points."""
        w, h = self.size
        p = np.asarray(p, dtype=np.float64)
        return p @ BOARD_TO_SAMPLE_R + np.array([w / 2, h / 2, 0.0])

    def board_to_sample(self, p) -> np.ndarray:
        """Board-frame points (..., 3) -> sample-frame points."""
        w, h = self.size
        return (np.asarray(p, dtype=np.float64) - np.array([w / 2, h / 2, 0.0])) @ BOARD_TO_SAMPLE_R


def surface_frame(transform) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(origin, normal, frame)`` of the surface z = 0 of patch coordinates moved by ``transform``.

    ``transform`` (4×4 affine, ``X_world = M X_patch``): origin = M·0, normal = (M⁻¹)ᵀ z normalized
    (:func:`gonio.geometry.transform_normals`; lecture notes 000, "Note on normals and spaces"),
    frame rows = local x (M·x orthogonalised against the normal), y = z × x, z = normal
    (:func:`gonio.geometry.frame_from_normal`). Shared by the renderer and the pipeline.
    """
    M = np.asarray(transform, dtype=np.float64)
    n = transform_normals(M, [0.0, 0.0, 1.0])
    return M[:3, 3].copy(), n, frame_from_normal(n, M[:3, :3] @ np.array([1.0, 0.0, 0.0]))


@dataclass(frozen=True)
class SampleMount:
    """A known sample mounting: where the sample surface is relative to the board plane.

    The lab measures (or machines) the mount and declares it; the pipeline then computes each
    pixel's surface point on the tilted plane and wi/wo in the sample's own frame
    (:func:`surface_frame`). Either tilt angles — ``X_world = T(0, 0, height) · R_y(tilt_y) ·
    R_x(tilt_x) · X_patch`` (rotations about the board's x then y axis through the sample centre,
    right-handed, degrees at this user boundary) — or a full 4×4 ``matrix`` (which then replaces
    the tilts and height).

    An undeclared tilt is *not* detected: per pose, the sample's shading cannot separate a tilt
    from the unknown BRDF, and the white reference lies on the board, not on the mount; the patch
    outline moves by only ~1–3 px for 5° at the simulated rig's geometry. Declare the mount.
    """

    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    height: float = 0.0
    matrix: tuple | None = None

    def __post_init__(self):
        for name in ("tilt_x_deg", "tilt_y_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and abs(float(v)) < 45.0):
                raise ConfigError.field(None, f"mount.{name}", v, "needs a number of degrees in (-45, 45)")
        if not (isinstance(self.height, (int, float, np.floating, np.integer)) and abs(float(self.height)) < 0.1):
            raise ConfigError.field(None, "mount.height", self.height, "needs metres in (-0.1, 0.1)")
        if self.matrix is not None:
            try:
                M = np.asarray(self.matrix, dtype=np.float64)
            except (TypeError, ValueError):
                M = np.zeros(0)
            ok = M.shape == (4, 4) and np.isfinite(M).all() and np.allclose(M[3], [0, 0, 0, 1])
            if ok:
                det = np.linalg.det(M[:3, :3])
                ok = det > 1e-6
            if not ok:
                raise ConfigError.field(None, "mount.matrix", self.matrix,
                                        "needs a finite 4x4 affine matrix (last row 0 0 0 1, positive determinant)")
            object.__setattr__(self, "matrix", tuple(tuple(float(x) for x in row) for row in M))

    @property
    def transform(self) -> np.ndarray:
        """The 4×4 affine map patch coordinates → sample (board-centred) frame."""
        if self.matrix is not None:
            return np.array(self.matrix, dtype=np.float64)
        ax, ay = np.radians(self.tilt_x_deg), np.radians(self.tilt_y_deg)
        rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
        ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
        M = np.eye(4)
        M[:3, :3] = ry @ rx
        M[2, 3] = self.height
        return M

    @property
    def is_flat(self) -> bool:
        """True when the sample lies in the board plane with the board's axes (M = I)."""
        flat = self.__dict__.get("_flat")
        if flat is None:  # the mount is immutable (frozen, numbers and tuples): computed once
            flat = bool(np.array_equal(self.transform, np.eye(4)))
            object.__setattr__(self, "_flat", flat)
        return flat

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(origin, normal, frame)`` of the sample surface, :func:`surface_frame` (computed once per mount, the
        mount being immutable; copies are returned, which the caller may change)."""
        cached = self.__dict__.get("_frame")
        if cached is None:
            cached = surface_frame(self.transform)
            object.__setattr__(self, "_frame", cached)
        return tuple(a.copy() for a in cached)

    def to_patch(self, p) -> np.ndarray:
        """World points (..., 3) → patch coordinates (``M⁻¹ X``; z = 0 on the sample surface)."""
        Minv = np.linalg.inv(self.transform)
        return np.asarray(p, dtype=np.float64) @ Minv[:3, :3].T + Minv[:3, 3]

    def to_dict(self) -> dict:
        d = {"tilt_x_deg": float(self.tilt_x_deg), "tilt_y_deg": float(self.tilt_y_deg), "height": float(self.height)}
        if self.matrix is not None:
            d = {"matrix": [list(r) for r in self.matrix]}
        return d

    @classmethod
    def from_dict(cls, d, source: str | None = None) -> "SampleMount":
        """From ``{"tilt_x_deg", "tilt_y_deg", "height"}`` or ``{"matrix": 4x4}``; unknown keys are an error."""
        if not isinstance(d, dict):
            raise ConfigError.field(source, "mount", d, "needs a table of tilt_x_deg, tilt_y_deg, height "
                                    "or matrix")
        unknown = set(d) - {"tilt_x_deg", "tilt_y_deg", "height", "matrix"}
        if unknown:
            raise ConfigError.field(source, f"mount.{sorted(unknown)[0]}", d[sorted(unknown)[0]],
                                    "unknown key (tilt_x_deg, tilt_y_deg, height or matrix)")
        if "matrix" in d and set(d) - {"matrix"}:
            raise ConfigError.field(source, "mount.matrix", d["matrix"], "give either matrix or tilts/height")
        try:
            return cls(**d)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None


@dataclass(frozen=True)
class TargetLayout:
    """Board, sample patch and white reference patch (rectangles in the sample frame, metres).

    The white reference is Lambertian with albedo ``white_albedo`` (per RGB channel, e.g. a
    calibrated Spectralon tile: 0.99). ``sample`` is in the patch's own coordinates; ``mount``
    (:class:`SampleMount`, default flat) places it relative to the board; the white reference lies
    on the board plane.
    """

    charuco: CharucoSpec = field(default_factory=CharucoSpec)
    sample: Rect = field(default_factory=lambda: Rect(-0.025, -0.025, 0.025, 0.025))
    white: Rect = field(default_factory=lambda: Rect(-0.105, -0.02, -0.065, 0.02))
    white_albedo: tuple[float, float, float] = (0.99, 0.99, 0.99)
    mount: SampleMount = field(default_factory=SampleMount)
    #: a sphere coated with the material (:class:`gonio.sphere.Sphere`, sample frame) measured instead of the flat
    #: patch, one sample per pixel (image-based acquisition, :mod:`gonio.sphere`); None: the flat sample
    sphere: object = None
    #: a cylinder lying on the board instead (:class:`gonio.sphere.cylinder.Cylinder`): its axis gives anisotropic
    #: slices; None: no cylinder
    cylinder: object = None

    @property
    def curved(self):
        """The curved sample measured per pixel (the sphere or the cylinder), or None for the flat patch."""
        return self.sphere if self.sphere is not None else self.cylinder

    def __post_init__(self):
        w, h = self.charuco.size
        board = Rect(-w / 2, -h / 2, w / 2, h / 2)
        for name, r in (("sample", self.sample), ("white", self.white)):
            if not (board.contains(r.x0, r.y0) and board.contains(r.x1, r.y1)):
                raise ConfigError.field(None, f"{name}", r, f"must lie on the {w:g} × {h:g} m board")
        if self.sample.overlaps(self.white):
            raise ConfigError.field(None, "white", self.white, "overlaps the sample patch")
        a = np.asarray(self.white_albedo, dtype=np.float64)
        if a.shape != (3,) or not np.all((a > 0) & (a <= 1)):
            raise ConfigError.field(None, "white_albedo", self.white_albedo, "needs 3 values in (0, 1]")
        if not isinstance(self.mount, SampleMount):
            raise ConfigError.field(None, "mount", self.mount, "needs a SampleMount")
        if self.sphere is not None:
            sp = self.sphere
            x, y, z = sp.centre
            if not board.contains(x - sp.radius, y - sp.radius) or not board.contains(x + sp.radius, y + sp.radius):
                raise ConfigError.field(None, "sphere.centre", list(sp.centre), "the sphere must stand on the board")
            if z < sp.radius - 1e-9:
                raise ConfigError.field(None, "sphere.centre", list(sp.centre),
                                        f"z below the radius {sp.radius:g} m: the sphere would cut the board")
            wx = min(max(x, self.white.x0), self.white.x1)
            wy = min(max(y, self.white.y0), self.white.y1)
            if (wx - x) ** 2 + (wy - y) ** 2 < sp.radius ** 2:
                raise ConfigError.field(None, "sphere.centre", list(sp.centre), "the sphere stands on the white patch")
        if self.cylinder is not None:
            from gonio.sphere.cylinder import check_on_board

            if self.sphere is not None:
                raise ConfigError.field(None, "cylinder", "[cylinder]", "a target holds a [sphere] or a [cylinder], "
                                        "not both")
            check_on_board(self.cylinder, board, self.white)

    def sample_corners(self) -> np.ndarray:
        """The sample patch's 4 corners in the sample (board-centred) frame, through the mount (4, 3)."""
        M = self.mount.transform
        return self.sample.corners() @ M[:3, :3].T + M[:3, 3]

    def to_dict(self) -> dict:
        """JSON-able description (the session manifest's ``target``), metres and degrees."""
        c = self.charuco
        return {"charuco": {"squares": list(c.squares), "square_length": c.square_length,
                            "marker_length": c.marker_length, "dictionary": c.dictionary},
                "sample": [self.sample.x0, self.sample.y0, self.sample.x1, self.sample.y1],
                "white": [self.white.x0, self.white.y0, self.white.x1, self.white.y1],
                "white_albedo": [float(a) for a in self.white_albedo], "mount": self.mount.to_dict(),
                **({"sphere": {"radius": self.sphere.radius, "centre": list(self.sphere.centre)}}
                   if self.sphere is not None else {}),
                **({"cylinder": {"radius": self.cylinder.radius, "length": self.cylinder.length,
                                 "axis": list(self.cylinder.axis), "centre": list(self.cylinder.centre)}}
                   if self.cylinder is not None else {})}

    @classmethod
    def from_dict(cls, d, source: str | None = None) -> "TargetLayout":
        """Inverse of :meth:`to_dict`; missing keys take the defaults; errors name ``source`` and the field."""
        if not isinstance(d, dict):
            raise ConfigError.field(source, "target", d, "needs a table")
        unknown = set(d) - {"charuco", "sample", "white", "white_albedo", "mount", "sphere", "cylinder"}
        if unknown:
            k = sorted(unknown)[0]
            raise ConfigError.field(source, f"target.{k}", d[k], "unknown key")
        kw = {}
        try:
            if "charuco" in d:
                kw["charuco"] = _charuco(d["charuco"])
            for name in ("sample", "white"):
                if name in d:
                    kw[name] = _rect(name, d[name])
            if "white_albedo" in d:
                kw["white_albedo"] = _albedo(d["white_albedo"])
            if "mount" in d:
                kw["mount"] = SampleMount.from_dict(d["mount"])
            if "sphere" in d:
                kw["sphere"] = _sphere(d["sphere"])
            if "cylinder" in d:
                from gonio.sphere.cylinder import cylinder_from_table

                kw["cylinder"] = cylinder_from_table(d["cylinder"], _number)
            return cls(**kw)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None
        except (TypeError, ValueError) as exc:  # pragma: no cover - every field is checked above
            raise ConfigError.field(source, "target", d, f"malformed: {exc}") from None


def _number(field_path: str, v) -> float:
    """A finite real number from a TARGET table, or a ConfigError naming ``field_path`` and the value."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
        raise ConfigError.field(None, field_path, v, "needs a finite number")
    return float(v)


def _rect(name: str, v) -> Rect:
    """``[x0, y0, x1, y1]`` (metres) with x0 < x1, y0 < y1; errors name ``name.x0`` ... and the value."""
    if not (isinstance(v, (list, tuple)) and len(v) == 4):
        raise ConfigError.field(None, name, v, "needs [x0, y0, x1, y1] in metres")
    x0, y0, x1, y1 = (_number(f"{name}.{k}", x) for k, x in zip(("x0", "y0", "x1", "y1"), v))
    if not x1 > x0:
        raise ConfigError.field(None, f"{name}.x1", x1, f"must exceed {name}.x0 = {x0:g} (as [x0, y0, x1, y1])")
    if not y1 > y0:
        raise ConfigError.field(None, f"{name}.y1", y1, f"must exceed {name}.y0 = {y0:g} (as [x0, y0, x1, y1])")
    return Rect(x0, y0, x1, y1)


def _albedo(v) -> tuple[float, float, float]:
    """``white_albedo``: 3 values (RGB) or one grey value, each in (0, 1]."""
    vals = list(v) if isinstance(v, (list, tuple)) else [v] * 3
    if len(vals) != 3 or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and 0 < a <= 1
                                 for a in vals):
        raise ConfigError.field(None, "white_albedo", v, "needs 3 values (or one grey value) in (0, 1]")
    return tuple(float(a) for a in vals)


_CHARUCO_KEYS = ("squares", "square_length", "marker_length", "dictionary")


def _sphere(v):
    """The ``[sphere]`` table: ``radius`` (metres) and ``centre`` ([x, y, z] metres in the sample frame; default
    ``[0, 0, radius]``, resting on the board's centre); errors name ``sphere.<key>`` and the value."""
    from gonio.sphere.geometry import Sphere

    if not isinstance(v, dict):
        raise ConfigError.field(None, "sphere", v, "needs a table: radius (m), centre = [x, y, z] (m)")
    unknown = sorted(set(v) - {"radius", "centre"})
    if unknown:
        raise ConfigError.field(None, f"sphere.{unknown[0]}", v[unknown[0]], "unknown key (radius, centre)")
    if "radius" not in v:
        raise ConfigError.field(None, "sphere.radius", None, "is required (metres)")
    r = _number("sphere.radius", v["radius"])
    c = v.get("centre", [0.0, 0.0, r])
    if not (isinstance(c, (list, tuple)) and len(c) == 3):
        raise ConfigError.field(None, "sphere.centre", c, "needs [x, y, z] in metres")
    centre = tuple(_number(f"sphere.centre.{k}", x) for k, x in zip("xyz", c))
    return Sphere(centre, r)



def _charuco(v) -> CharucoSpec:
    """The ``[charuco]`` table; errors name ``charuco.<key>`` and the value."""
    if not isinstance(v, dict):
        raise ConfigError.field(None, "charuco", v, f"needs a table of {', '.join(_CHARUCO_KEYS)}")
    unknown = sorted(set(v) - set(_CHARUCO_KEYS))
    if unknown:
        raise ConfigError.field(None, f"charuco.{unknown[0]}", v[unknown[0]],
                                f"unknown key ({', '.join(_CHARUCO_KEYS)})")
    kw = dict(v)
    if "squares" in kw:
        sq = kw["squares"]
        if not (isinstance(sq, (list, tuple)) and len(sq) == 2
                and all(isinstance(n, int) and not isinstance(n, bool) for n in sq)):
            raise ConfigError.field(None, "charuco.squares", sq, "needs [columns, rows], two integers")
        kw["squares"] = tuple(sq)
    for k in ("square_length", "marker_length"):
        if k in kw:
            kw[k] = _number(f"charuco.{k}", kw[k])
    if "dictionary" in kw and not isinstance(kw["dictionary"], str):
        raise ConfigError.field(None, "charuco.dictionary", kw["dictionary"], "needs a cv2.aruco dictionary name")
    return CharucoSpec(**kw)


def load_target(path) -> TargetLayout:
    """A :class:`TargetLayout` from a TOML file with the keys of :meth:`TargetLayout.to_dict`, e.g.::

        sample = [-0.025, -0.025, 0.025, 0.025]   # metres, patch coordinates
        [mount]                                   # the measured sample mounting
        tilt_x_deg = 5.0
        tilt_y_deg = 0.0
        height = 0.002

    Missing keys take the defaults; errors name the file and the field.
    """
    from gonio.config import read_toml

    layout = TargetLayout.from_dict(read_toml(path, "--target"), source=str(path))
    try:
        layout.charuco.check_dictionary()
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return layout
