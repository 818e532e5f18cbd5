"""The camera description a lab writes once: intrinsics, noise and how the camera encodes light.

A ``CAMERA.toml`` (``gonio measure --calibration``)::

    width = 1280
    height = 960
    focal_px = 1450.0          # or K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    dist = [0, 0, 0, 0, 0]     # optional, OpenCV's 4/5/8/12/14 coefficients

    [noise]                    # optional, EMVA 1288 (gonio.pipeline.target.NoiseModel)
    dn_per_electron = 0.2
    read_noise_e = 3.0
    full_well_e = 20000

    [camera]
    linear = true              # pixel values proportional to exposure (raw 10-16-bit sensors)
    bit_depth = 12             # 8, 10, 12, 14 or 16
    black_level = 64           # pedestal in DN
    # non-linear 8-bit cameras instead: linear = false, bit_depth = 8,
    #   response = "RESPONSE.npz"   (from `gonio camera response`; relative to this file)
    trigger = "none"           # or "controller": the rig controller fires each exposure
    exposure_unit = 1e-4       # seconds per CAP_PROP_EXPOSURE unit (V4L2: 100 µs)
    backend = "v4l2"           # any, v4l2, gstreamer, ffmpeg (OpenCV), or aravis (GenICam, below)

A GenICam camera (GigE Vision / USB3 Vision, :mod:`gonio.rig.aravis`) sets ``backend = "aravis"``,
``linear = true`` and ``pixel_format`` (``Mono8``...``Mono16``, ``RGB8``, ``BayerRG8``...; its bit depth
is implied and ``bit_depth``, if given, must match), optionally ``gain_unit = "dB"`` (SFNC, default)
or ``"raw"``; ``gonio measure --camera`` then names the device (``gonio camera list``) or
``gige://ADDRESS``.

A non-linear camera is usable in a session only through its inverse response curve
(:class:`ResponseCurve`, Debevec & Malik, SIGGRAPH 1997): frames are mapped through it to linear
16-bit values before the pipeline sees them, so the pipeline's refusal of non-linear frames stays a
real check. The curve is stored as plain arrays in an ``.npz`` (no pickle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from gonio.errors import ConfigError
from gonio.rig.interfaces import Frame

__all__ = ["ResponseCurve", "CameraSettings", "CameraDescription", "load_camera_calibration", "LinearizedCamera",
           "BACKENDS", "LINEARIZED_BIT_DEPTH"]

#: ``[camera] backend`` names → ``cv2.CAP_*`` API preference (values as in OpenCV's videoio). ``aravis``
#: is gonio's own GenICam backend (:mod:`gonio.rig.aravis`), not OpenCV's (absent from its pip wheels).
BACKENDS = {"any": 0, "v4l2": 200, "gstreamer": 1800, "ffmpeg": 1900, "aravis": 2100}
#: Bit depth of frames linearized through a response curve (uint16, full scale = the 8-bit value 255).
LINEARIZED_BIT_DEPTH = 16
#: Lens aperture (for the detector solid angle, gonio.session.detector): a diameter, or f-number + focal length.
_LENS_KEYS = {"aperture_diameter_m", "f_number", "focal_length_m"}
#: What `gonio camera calibrate` / `gonio camera noise` measured (informational records: the intrinsics' σ,
#: residuals and coverage; EMVA 1288's dark current, DSNU, PRNU, linearity): numbers, strings, lists of them.
_RECORD_TABLES = ("intrinsics", "emva1288")
_TOP_KEYS = {"width", "height", "focal_px", "K", "dist", "noise", "camera", "radiometric_scale",
             *_RECORD_TABLES} | _LENS_KEYS
_NOISE_KEYS = {"dn_per_electron", "read_noise_e", "full_well_e"}
_CAMERA_KEYS = {"linear", "bit_depth", "black_level", "response", "trigger", "exposure_unit", "backend",
                "pixel_format", "gain_unit"}
_GAIN_UNITS = ("dB", "raw")
_TRIGGERS = ("none", "controller")


# -- the inverse response curve ------------------------------------------------------------------
@dataclass(frozen=True)
class ResponseCurve:
    """Inverse camera response of an 8-bit camera: relative exposure for each pixel value, per channel.

    ``inverse`` has shape (256, C) (C = 1 or 3), is non-decreasing and normalized so that the value
    255 maps to 1 in every channel. It comes from Debevec & Malik's recovery ("Recovering high
    dynamic range radiance maps from photographs", SIGGRAPH 1997): ``g(Z) = ln E + ln Δt``, here
    ``exp(g)`` as returned by :func:`gonio.pipeline.hdr.calibrate_response`.
    """

    inverse: np.ndarray
    exposures: tuple[float, ...] = ()
    source: str | None = None

    def __post_init__(self):
        inv = np.asarray(self.inverse, dtype=np.float64)
        where = self.source or "response curve"
        if inv.ndim == 3:
            inv = inv.reshape(inv.shape[0], -1)
        if inv.ndim == 1:
            inv = inv[:, None]
        if inv.shape not in ((256, 1), (256, 3)):
            raise ConfigError.field(where, "inverse_response.shape", tuple(np.shape(self.inverse)),
                                    "must be (256,), (256, 1, 3) or (256, 3): one value per 8-bit level")
        if not np.isfinite(inv).all() or (inv < 0).any() or (inv[-1] <= 0).any():
            raise ConfigError.field(where, "inverse_response", "non-finite or negative values",
                                    "must be finite, >= 0 and positive at 255; recalibrate")
        inv = np.maximum.accumulate(inv, axis=0)  # Debevec's curve is monotone up to noise at the ends
        inv = inv / inv[-1]
        inv.setflags(write=False)
        object.__setattr__(self, "inverse", inv)
        object.__setattr__(self, "exposures", tuple(float(t) for t in self.exposures))

    @classmethod
    def from_debevec(cls, response: np.ndarray, exposures=(), source: str | None = None) -> "ResponseCurve":
        """From the (256, 1, 3) array of :func:`gonio.pipeline.hdr.calibrate_response`."""
        return cls(inverse=np.asarray(response), exposures=tuple(exposures), source=source)

    # -- files (npz of plain arrays, read with allow_pickle=False) -------------------------------
    def save(self, path) -> None:
        """Write ``inverse_response`` (256, C) float64 and ``exposures`` (seconds) to an ``.npz``."""
        with open(path, "wb") as fh:
            np.savez(fh, inverse_response=self.inverse, exposures=np.asarray(self.exposures, dtype=np.float64))

    @classmethod
    def load(cls, path, *, source: str | None = None, field_name: str = "response") -> "ResponseCurve":
        """Read a curve written by :meth:`save`; ConfigError naming ``source``/``field_name`` otherwise."""
        where = source or str(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                if "inverse_response" not in z.files:
                    raise ConfigError.field(where, field_name, str(path),
                                            "has no 'inverse_response' array (write it with `gonio camera response`)")
                inv = np.array(z["inverse_response"])
                exps = np.array(z["exposures"]) if "exposures" in z.files else np.zeros(0)
        except OSError as exc:
            raise ConfigError.field(where, field_name, str(path),
                                    f"cannot read: {exc.strerror or exc}") from None
        except (ValueError, EOFError) as exc:
            why = "holds pickled objects, which gonio never loads" if "pickle" in str(exc) else str(exc)
            raise ConfigError.field(where, field_name, str(path),
                                    f"not a response .npz from `gonio camera response` ({why})") from None
        if inv.dtype.kind not in "fiu":
            raise ConfigError.field(where, field_name, str(path), f"inverse_response has dtype {inv.dtype}")
        return cls(inverse=inv, exposures=tuple(np.asarray(exps, dtype=np.float64).ravel()), source=str(path))

    def to_dict(self) -> dict:
        return {"inverse_response": self.inverse.tolist(), "exposures": list(self.exposures),
                "file": self.source}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "ResponseCurve":
        if not isinstance(d, Mapping) or "inverse_response" not in d:
            raise ConfigError.field(source, "camera.response", type(d).__name__, "needs inverse_response")
        try:
            inv = np.asarray(d["inverse_response"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError.field(source, "camera.response.inverse_response", "...", "not numbers") from None
        return cls(inverse=inv, exposures=tuple(d.get("exposures", ())), source=d.get("file"))

    # -- use -----------------------------------------------------------------------------------------
    def lut(self) -> np.ndarray:
        """(256, C) float64 table: linear value in [0, 65535] for each 8-bit level."""
        return self.inverse * float((1 << LINEARIZED_BIT_DEPTH) - 1)

    def linearize(self, frame: Frame) -> Frame:
        """The frame mapped through the curve: uint16, bit depth 16, ``linear=True``.

        Value ``v`` → ``round(65535 · E(v) / E(255))`` per channel (E = the inverse response), so a
        saturated 8-bit value stays at the saturation level and the pipeline's saturation test
        holds. The black level becomes the mapped value of 0 (mean over channels). Uses
        :func:`gonio.camera_model.lookup_response` for the per-channel lookup.
        """
        from gonio.camera_model import lookup_response as linearize

        px = frame.pixels
        if not isinstance(px, np.ndarray) or px.dtype != np.uint8 or frame.bit_depth != 8:
            raise ConfigError.field(self.source, "camera.response", getattr(px, "dtype", type(px)),
                                    "a response curve applies to 8-bit frames only (set bit_depth = 8)")
        lut = self.lut()
        lin = linearize(px, lut)
        out = np.rint(lin).astype(np.uint16)
        if px.ndim == 2:
            out = out[..., 0]
        return replace(frame, pixels=out, bit_depth=LINEARIZED_BIT_DEPTH, linear=True,
                       black_level=float(lut[0].mean()),
                       meta={**dict(frame.meta), "linearized": True, "raw_bit_depth": 8})


# -- the [camera] table ------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraSettings:
    """How the camera encodes light and how it is driven (the ``[camera]`` table).

    Without a ``[camera]`` table the camera is taken as an 8-bit non-linear webcam (OpenCV's usual
    output), which a session refuses until a response curve is given (:meth:`check_session`).
    """

    linear: bool = False
    bit_depth: int = 8
    black_level: float = 0.0
    response: ResponseCurve | None = None
    trigger: str = "none"
    exposure_unit: float = 1e-4
    backend: str = "v4l2"
    #: GenICam pixel format (``backend = "aravis"`` only).
    pixel_format: str | None = None
    #: How a GenICam camera's Gain register counts (``backend = "aravis"`` only).
    gain_unit: str = "dB"

    def __post_init__(self):
        if self.bit_depth not in (8, 10, 12, 14, 16):
            raise ConfigError.field(None, "camera.bit_depth", self.bit_depth, "must be 8, 10, 12, 14 or 16")
        if self.trigger not in _TRIGGERS:
            raise ConfigError.field(None, "camera.trigger", self.trigger, f"must be one of {', '.join(_TRIGGERS)}")
        if self.backend not in BACKENDS:
            raise ConfigError.field(None, "camera.backend", self.backend, f"must be one of {', '.join(BACKENDS)}")
        if self.gain_unit not in _GAIN_UNITS:
            raise ConfigError.field(None, "camera.gain_unit", self.gain_unit, f"must be one of {', '.join(_GAIN_UNITS)}")
        if self.backend == "aravis":
            from gonio.rig.aravis import PIXEL_FORMATS

            if self.pixel_format not in PIXEL_FORMATS:
                raise ConfigError.field(None, "camera.pixel_format", self.pixel_format,
                                        f"a GenICam camera needs one of {', '.join(PIXEL_FORMATS)}")
            if not self.linear:
                raise ConfigError.field(None, "camera.linear", self.linear, "GenICam raw pixel formats are linear: "
                                        "set linear = true")
            if self.bit_depth != PIXEL_FORMATS[self.pixel_format][0]:
                raise ConfigError.field(None, "camera.bit_depth", self.bit_depth,
                                        f"{self.pixel_format} has {PIXEL_FORMATS[self.pixel_format][0]} bits")
        elif self.pixel_format is not None:
            raise ConfigError.field(None, "camera.pixel_format", self.pixel_format, "is for backend = \"aravis\"")

    @property
    def backend_id(self) -> int:
        return BACKENDS[self.backend]

    def check_session(self, source: str | None = None) -> None:
        """Refuse, before anything moves, a camera whose frames the pipeline could not use."""
        if not self.linear and self.response is None:
            raise ConfigError.field(
                source, "camera.linear", False,
                "a non-linear camera needs its response curve: run `gonio camera response --camera N "
                "--exposures 0.002,0.004,...,0.128 -o RESPONSE.npz` on a static scene and add "
                "response = \"RESPONSE.npz\" to [camera] (or set linear = true and bit_depth for a linear camera)")

    def to_dict(self) -> dict:
        d = {"linear": self.linear, "bit_depth": self.bit_depth, "black_level": self.black_level,
             "trigger": self.trigger, "exposure_unit": self.exposure_unit, "backend": self.backend}
        if self.backend == "aravis":
            d.update(pixel_format=self.pixel_format, gain_unit=self.gain_unit)
        if self.response is not None:
            d["response"] = self.response.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "CameraSettings":
        """From the manifest's ``calibration.camera`` (the response curve stored inline)."""
        d = dict(d)
        resp = d.pop("response", None)
        kw = _camera_fields(d, source, base=None)
        if resp is not None:
            kw["response"] = ResponseCurve.from_dict(resp, source)
        return _settings(kw, source)


def _settings(kw: dict, source: str | None) -> CameraSettings:
    try:
        s = CameraSettings(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None
    if s.response is not None and (s.linear or s.bit_depth != 8):
        raise ConfigError.field(source, "camera.response", s.response.source,
                                "is for non-linear 8-bit cameras: set linear = false and bit_depth = 8")
    if s.black_level >= 2 ** s.bit_depth - 1:
        raise ConfigError.field(source, "camera.black_level", s.black_level,
                                f"must be below the {s.bit_depth}-bit full scale {2 ** s.bit_depth - 1} DN")
    return s


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _camera_fields(d: Mapping[str, Any], source: str | None, base: Path | None) -> dict:
    unknown = sorted(set(d) - _CAMERA_KEYS - {"response"})
    if unknown:
        raise ConfigError.field(source, f"camera.{unknown[0]}", d[unknown[0]],
                                f"unknown key (known: {', '.join(sorted(_CAMERA_KEYS))})")
    kw: dict = {}
    if "linear" in d:
        if not isinstance(d["linear"], bool):
            raise ConfigError.field(source, "camera.linear", d["linear"], "must be true or false")
        kw["linear"] = d["linear"]
    if "bit_depth" in d:
        v = d["bit_depth"]
        if not isinstance(v, int) or isinstance(v, bool):
            raise ConfigError.field(source, "camera.bit_depth", v, "must be 8, 10, 12, 14 or 16")
        kw["bit_depth"] = v  # the allowed values: CameraSettings.__post_init__
    if "black_level" in d:
        v = d["black_level"]
        if not _is_number(v) or v < 0:
            raise ConfigError.field(source, "camera.black_level", v, "must be a number >= 0 (DN)")
        kw["black_level"] = float(v)
    if "exposure_unit" in d:
        v = d["exposure_unit"]
        if not _is_number(v) or v <= 0:
            raise ConfigError.field(source, "camera.exposure_unit", v, "must be a positive number of seconds")
        kw["exposure_unit"] = float(v)
    if d.get("backend") == "aravis" and "pixel_format" in d and "bit_depth" not in d:
        from gonio.rig.aravis import PIXEL_FORMATS

        if d["pixel_format"] in PIXEL_FORMATS:  # the format implies the depth
            kw["bit_depth"] = PIXEL_FORMATS[d["pixel_format"]][0]
    for key in ("pixel_format", "gain_unit"):
        if key in d:
            if not isinstance(d[key], str):
                raise ConfigError.field(source, f"camera.{key}", d[key], "must be a string")
            kw[key] = d[key]
    for key, allowed in (("trigger", _TRIGGERS), ("backend", tuple(BACKENDS))):
        if key in d:
            v = d[key]
            if not isinstance(v, str):
                raise ConfigError.field(source, f"camera.{key}", v, f"must be one of {', '.join(allowed)}")
            kw[key] = v.lower() if v.lower() in allowed else v  # a bad value: CameraSettings.__post_init__ says so
    if base is not None and "response" in d:
        v = d["response"]
        if not isinstance(v, str) or not v:
            raise ConfigError.field(source, "camera.response", v, "must be the path of a .npz from `gonio camera response`")
        p = Path(v).expanduser()
        p = p if p.is_absolute() else base / p
        if not p.is_file():
            raise ConfigError.field(source, "camera.response", v, f"no such file ({p})")
        kw["response"] = ResponseCurve.load(p, source=source, field_name="camera.response")
    return kw


# -- the whole description ---------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraDescription:
    """Geometric + radiometric calibration (:class:`gonio.pipeline.target.CameraCalibration`) and the
    camera's encoding (:class:`CameraSettings`), as recorded in a session manifest's ``calibration``."""

    calibration: Any  # gonio.pipeline.target.CameraCalibration
    camera: CameraSettings = field(default_factory=CameraSettings)
    source: str | None = None
    #: ``aperture_diameter_m``, or ``f_number`` + ``focal_length_m``, as given (validated).
    lens: Mapping[str, float] = field(default_factory=dict)
    #: the noise-model fields every σ rests on that the file did not give (gonio's defaults stand in for them)
    noise_defaults: tuple[str, ...] = ()
    #: ``[intrinsics]`` and ``[emva1288]`` as measured (``gonio camera calibrate`` / ``noise``), if given
    records: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    @property
    def intrinsics_sigma(self) -> dict | None:
        """Standard uncertainties of ``fx, fy, cx, cy`` (px) and ``dist`` (list) as `gonio camera calibrate`
        measured them (``[intrinsics]``), or None for a description typed by hand."""
        rec = self.records.get("intrinsics") or {}
        keys = ("sigma_fx", "sigma_fy", "sigma_cx", "sigma_cy")
        if not all(k in rec for k in keys):
            return None
        return {k[6:]: float(rec[k]) for k in keys} | {"dist": list(rec.get("sigma_dist", []))}

    def to_dict(self) -> dict:
        c = self.calibration
        d = {"width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist(),
             "noise": dict(c.noise.__dict__), "camera": self.camera.to_dict(), **dict(self.lens)}
        if c.radiometric_scale is not None:
            d["radiometric_scale"] = list(c.radiometric_scale)
        d.update({k: dict(v) for k, v in self.records.items()})
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "CameraDescription":
        """From a manifest's ``calibration`` (sessions recorded before ``camera`` existed: defaults)."""
        from gonio.camera_model import CameraCalibration, NoiseModel

        try:
            noise = NoiseModel(**_noise_fields(d.get("noise", {}), source))
            calib = CameraCalibration(K=d["K"], width=int(d["width"]), height=int(d["height"]), dist=d["dist"],
                                      noise=noise, radiometric_scale=_radiometric(d, source))
        except KeyError as exc:
            raise ConfigError.field(source, f"calibration.{exc.args[0]}", None, "missing") from None
        return cls(calibration=calib, camera=CameraSettings.from_dict(d.get("camera", {}), source), source=source,
                   lens=_lens_fields(d, source), records=_records(d, source))


def _lens_fields(d, source: str | None) -> dict:
    """The lens-aperture keys present in ``d``, each a positive number; f_number and focal_length_m together."""
    lens = {k: d[k] for k in sorted(_LENS_KEYS) if k in d}
    for k, v in lens.items():
        if not _is_number(v) or not (math.isfinite(v) and v > 0):
            raise ConfigError.field(source, k, v, "must be a positive number")
    if ("f_number" in lens) != ("focal_length_m" in lens):
        missing = "f_number" if "f_number" not in lens else "focal_length_m"
        raise ConfigError.field(source, missing, None, "missing (f_number and focal_length_m go together)")
    return {k: float(v) for k, v in lens.items()}


def _records(d, source: str | None) -> dict:
    """The ``[intrinsics]`` / ``[emva1288]`` tables present in ``d``: tables of numbers, strings, booleans and
    lists of them (nothing else: they are records, read by people and by the uncertainty budget)."""
    def ok(v) -> bool:
        if isinstance(v, (list, tuple)):
            return len(v) <= 64 and all(ok(x) for x in v)
        return isinstance(v, (str, bool)) or _is_number(v)

    out = {}
    for name in _RECORD_TABLES:
        if name not in d:
            continue
        table = d[name]
        if not isinstance(table, Mapping):
            raise ConfigError.field(source, name, table, "must be a table")
        for k, v in table.items():
            if not ok(v):
                raise ConfigError.field(source, f"{name}.{k}", v, "must be a number, string or a list of them")
        out[name] = dict(table)
    return out


def _noise_fields(d, source: str | None) -> dict:
    if not isinstance(d, Mapping):
        raise ConfigError.field(source, "noise", d, "must be a table")
    unknown = sorted(set(d) - _NOISE_KEYS)
    if unknown:
        raise ConfigError.field(source, f"noise.{unknown[0]}", d[unknown[0]],
                                f"unknown key (known: {', '.join(sorted(_NOISE_KEYS))})")
    kw = {}
    for key, v in d.items():
        if v is None and key == "full_well_e":
            continue
        if not _is_number(v) or v < 0 or (v == 0 and key != "read_noise_e"):
            raise ConfigError.field(source, f"noise.{key}", v,
                                    "must be a number >= 0" if key == "read_noise_e" else "must be a positive number")
        kw[key] = float(v)
    return kw


def _radiometric(d, source):
    v = d.get("radiometric_scale")
    if v is None:
        return None
    if not isinstance(v, (list, tuple)) or len(v) != 3 or not all(_is_number(x) and x > 0 for x in v):
        raise ConfigError.field(source, "radiometric_scale", v, "must be 3 positive numbers (R, G, B)")
    return tuple(float(x) for x in v)


def _positive_int(data, key, source) -> int:
    if key not in data:
        raise ConfigError.field(source, key, None, "missing")
    v = data[key]
    if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
        raise ConfigError.field(source, key, v, "must be a positive integer (pixels)")
    return v


def load_camera_calibration(path, *, for_session: bool = True) -> CameraDescription:
    """Read a ``CAMERA.toml`` (see the module docstring) into a :class:`CameraDescription`.

    Every bad value is a one-line :class:`~gonio.errors.ConfigError` naming the file, the field and
    the value. With ``for_session`` (default) a non-linear camera without a response curve is refused
    here, before a session starts (:meth:`CameraSettings.check_session`).
    """
    from gonio.config import read_toml
    from gonio.camera_model import CameraCalibration, NoiseModel

    src = str(path)
    data = read_toml(path, "--calibration")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ConfigError.field(src, unknown[0], data[unknown[0]], f"unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    width, height = _positive_int(data, "width", src), _positive_int(data, "height", src)
    noise_fields = _noise_fields(data.get("noise", {}), src)
    noise = NoiseModel(**noise_fields)
    noise_defaults = tuple(k for k in ("dn_per_electron", "read_noise_e") if k not in noise_fields)
    kw: dict = {"noise": noise, "radiometric_scale": _radiometric(data, src)}
    if "dist" in data:
        v = data["dist"]
        if not isinstance(v, list) or not all(_is_number(x) for x in v) or len(v) not in (4, 5, 8, 12, 14):
            raise ConfigError.field(src, "dist", v, "must be a list of 4, 5, 8, 12 or 14 numbers")
        kw["dist"] = v
    if "K" in data:
        v = data["K"]
        ok = (isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) and len(r) == 3 for r in v)
              and all(_is_number(x) for r in v for x in r))
        if not ok:
            raise ConfigError.field(src, "K", v, "must be a 3x3 list of numbers [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        try:
            calib = CameraCalibration(K=v, width=width, height=height, **kw)
        except ConfigError as exc:
            raise ConfigError(f"{src}: {exc}") from None
    else:
        if "focal_px" not in data:
            raise ConfigError.field(src, "focal_px", None, "missing (or give K)")
        f = data["focal_px"]
        if not _is_number(f) or f <= 0:
            raise ConfigError.field(src, "focal_px", f, "must be a positive number (pixels)")
        calib = CameraCalibration.pinhole(width, height, float(f), **kw)
    cam = data.get("camera", {})
    if not isinstance(cam, dict):
        raise ConfigError.field(src, "camera", cam, "must be a table [camera]")
    settings = _settings(_camera_fields(cam, src, base=Path(path).parent), src)
    if for_session:
        settings.check_session(src)
    return CameraDescription(calibration=calib, camera=settings, source=src, lens=_lens_fields(data, src),
                             noise_defaults=noise_defaults, records=_records(data, src))


class LinearizedCamera:
    """Any :class:`~gonio.rig.interfaces.Camera` whose 8-bit frames are mapped through a
    :class:`ResponseCurve` (used for cameras that do not linearize themselves, e.g. the simulated one)."""

    def __init__(self, camera, response: ResponseCurve):
        self.camera = camera
        self.response = response

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        return self.response.linearize(self.camera.capture(exposure, gain, timeout=timeout))

    def close(self) -> None:
        self.camera.close()
