"""The simulated camera: renders what the rig's camera would see, through the same ``Camera`` interface.

Scene (sample frame = world frame): a ChArUco board in the plane z = 0 centred on the sample, the
sample patch carrying a :mod:`gonio.brdf` model (optionally tilted/transformed), a Lambertian white
reference patch, a point light with 1/r² falloff. Per-pixel ray/plane intersection gives per-pixel
wi/wo, so the pixels of one frame see slightly different angles.

Rendering is split in two: the noiseless electron rate image depends only on the camera pose and
the light position and is cached; :meth:`SimCamera.capture` scales it by exposure and the light's
current output and adds the sensor model (shot, read, dark noise, full well, gain, black level,
quantization). The rig wiring (``sim/rig.py``) calls :meth:`SimCamera.set_pose` and
:meth:`SimCamera.set_light` per pose and may pass ``light_output`` so that the camera sees the same
output the controller emulator's reference photodiode reports.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gonio.brdf.base import BRDF
from gonio.errors import ConfigError, HardwareError
from gonio.geometry import dot, normalize, to_local
from gonio.pipeline.target import CameraCalibration, CameraPose, NoiseModel, TargetLayout, surface_frame
from gonio.rig.interfaces import Clock, Frame, PhotodiodeReading
from sim import compiled, sensor_noise
from sim.compile_lock import serialized

__all__ = ["SensorModel", "SimScene", "SimCamera", "SceneLight", "normal_table", "board_texture",
           "blurred_board_texture"]

#: Below this mean count (electrons) shot noise is drawn from the exact Poisson law (by inversion,
#: :mod:`sim.sensor_noise`); above it from its normal approximation N(μ, μ), whose CDF error is below 1 % of
#: σ there (Berry–Esseen bound ~0.4/√μ on the CDF; the mean and variance are exact in both cases).
POISSON_EXACT_BELOW = 30.0


#: Wichura's algorithm AS 241 (PPND16), "The percentage points of the normal distribution", Applied Statistics
#: 37(3), 1988, 477-484: the rational approximations of Φ⁻¹ (relative error ~1e-16) for |p − ½| ≤ 0.425 (in
#: r = 0.180625 − q²), for r = √(−ln min(p, 1 − p)) ≤ 5 (in r − 1.6) and beyond (in r − 5); numerators and
#: denominators, constant term first
_AS241 = (
    ((3.387132872796366608, 133.14166789178437745, 1971.5909503065514427, 13731.693765509461125,
      45921.953931549871457, 67265.770927008700853, 33430.575583588128105, 2509.0809287301226727),
     (1.0, 42.313330701600911252, 687.1870074920579083, 5394.1960214247511077, 21213.794301586595867,
      39307.89580009271061, 28729.085735721942674, 5226.495278852545925)),
    ((1.42343711074968357734, 4.6303378461565452959, 5.7694972214606914055, 3.64784832476320460504,
      1.27045825245236838258, 0.24178072517745061177, 0.0227238449892691845833, 7.7454501427834140764e-4),
     (1.0, 2.05319162663775882187, 1.6763848301838038494, 0.68976733498510000455, 0.14810397642748007459,
      0.0151986665636164571966, 5.475938084995344946e-4, 1.05075007164441684324e-9)),
    ((6.6579046435011037772, 5.4637849111641143699, 1.7848265399172913358, 0.29656057182850489123,
      0.026532189526576123093, 0.0012426609473880784386, 2.71155556874348757815e-5, 2.01033439929228813265e-7),
     (1.0, 0.59983220655588793769, 0.13692988092273580531, 0.0148753612908506148525, 7.868691311456132591e-4,
      1.8463183175100546818e-5, 1.4215117583164458887e-7, 2.04426310338993978564e-15)),
)


def _ratio(coef, x):
    """A rational function of ``x`` (numerator and denominator coefficients, constant term first) by Horner."""
    num, den = (np.zeros_like(x) for _ in range(2))
    for a, b in zip(reversed(coef[0]), reversed(coef[1])):
        num, den = num * x + a, den * x + b
    return num / den


def inverse_normal(p) -> np.ndarray:
    """Φ⁻¹(p) for 0 < p < 1, float64: Wichura's AS 241 (:data:`_AS241`; relative error ~1e-16, within 1.1e-15 of
    ``scipy.special.ndtri`` on :func:`normal_table`'s points), without importing SciPy's special functions (a
    quarter of a second of a ``gonio measure --sim`` process)."""
    p = np.asarray(p, dtype=np.float64)
    q = p - 0.5
    out = np.empty_like(p)
    central = np.abs(q) <= 0.425
    qc = q[central]
    out[central] = qc * _ratio(_AS241[0], 0.180625 - qc * qc)
    tail = ~central
    r = np.sqrt(-np.log(np.where(q[tail] < 0, p[tail], 1.0 - p[tail])))
    v = np.where(r <= 5.0, _ratio(_AS241[1], r - 1.6), _ratio(_AS241[2], r - 5.0))
    out[tail] = np.where(q[tail] < 0, -v, v)
    return out


@functools.lru_cache(maxsize=1)
def normal_table() -> np.ndarray:
    """The 2¹⁶ standard-normal quantiles Φ⁻¹((k + ½)/2¹⁶), k = 0 … 2¹⁶ − 1 (:func:`inverse_normal`), float32,
    rescaled to unit variance (inverse transform sampling: Devroye, *Non-Uniform Random Variate Generation*, 1986,
    §II.2). Indexing it with uniform 16-bit integers draws from a 2¹⁶-point distribution that matches
    N(0, 1) in mean and variance, with values spaced < 4·10⁻⁵ σ apart near 0 and |z| ≤ 4.33. (The same float32
    table, bit for bit, as from ``scipy.special.ndtri``: tests/pipeline/test_dark_set_exact.py.)"""
    q = inverse_normal((np.arange(1 << 16, dtype=np.float64) + 0.5) / (1 << 16))
    q /= np.sqrt(np.mean(q * q))
    table = q.astype(np.float32)
    table.flags.writeable = False
    return table


def shade_board_numpy(px, py, hit, albedo, sx, sy, sz2, intensity_z, k):
    """The board's irradiance ``I z_S / r³`` (= I cos θ / r², a point source over the plane z = 0) at its points
    ``(px, py)`` seen by the pixels, and the electron rates ``albedo · irradiance · k`` (per channel, 0 where a
    pixel's ray misses the board), all float32: ``(irr (H, W), rate (H, W, 3))``. ``sz2`` is z_S², ``intensity_z``
    I · z_S, ``k`` the responsivity over π (3,). The reference of :func:`shade_board_compiled`."""
    irr = np.subtract(sx, px)
    irr *= irr
    ly = np.subtract(sy, py)
    ly *= ly
    irr += ly
    irr += sz2  # r²
    r = np.sqrt(irr, out=ly)
    irr *= r  # r³
    np.divide(intensity_z, irr, out=irr)
    shade = albedo * irr
    shade *= hit
    return irr, np.multiply(shade[..., None], k)


def _shade_board_loop(px, py, hit, albedo, sx, sy, sz2, intensity_z, k, irr, rate):
    """:func:`shade_board_numpy` per pixel (compiled by numba: the same float32 operations in the same order), the
    irradiance first, then the rates (``rate`` flat, three per pixel): two loops that vectorize."""
    for i in range(px.size):
        dx = sx - px[i]
        dy = sy - py[i]
        r2 = dx * dx + dy * dy + sz2
        irr[i] = intensity_z / (r2 * np.sqrt(r2))
    k0, k1, k2 = k[0], k[1], k[2]
    for i in range(px.size):
        sh = albedo[i] * irr[i]
        sh = sh * (np.float32(1.0) if hit[i] else np.float32(0.0))
        rate[3 * i] = sh * k0
        rate[3 * i + 1] = sh * k1
        rate[3 * i + 2] = sh * k2


@functools.lru_cache(maxsize=1)
def _shade_board_kernel():
    import numba

    # error_model="numpy": a division by zero gives inf as NumPy's does instead of raising (no check in the loop,
    # which then vectorizes)
    return serialized(numba.njit(cache=True, nogil=True, error_model="numpy")(_shade_board_loop))


def shade_board_compiled(px, py, hit, albedo, sx, sy, sz2, intensity_z, k):
    """:func:`shade_board_numpy` in numba (:func:`_shade_board_loop`): the same numbers bit for bit."""
    shape = px.shape
    irr = np.empty(shape, dtype=np.float32)
    rate = np.empty(shape + (3,), dtype=np.float32)
    _shade_board_kernel()(np.ascontiguousarray(px).reshape(-1), np.ascontiguousarray(py).reshape(-1),
                          np.ascontiguousarray(hit).reshape(-1), np.ascontiguousarray(albedo).reshape(-1),
                          sx, sy, sz2, intensity_z, np.ascontiguousarray(k, dtype=np.float32),
                          irr.reshape(-1), rate.reshape(-1))
    return irr, rate


def board_points_numpy(x, y, R, C, inv, origin):
    """Where the pixels' rays ``Rᵀ(x, y, 1)`` meet the board plane z = 0: ``C − C_z d / d_z`` (no normalization
    needed), whether they meet it (``d_z < −10⁻⁶`` and the camera above the plane) and the texture coordinates
    there (``inv`` texels per metre, ``origin`` the texel coordinates of the board point (0, 0)), float32 (H, W):
    ``(px, py, hit, mx, my)``. ``x`` (1, W) or (H, W) and ``y`` (H, 1) or (H, W): the undistorted normalized image
    coordinates, float32. The reference of :func:`board_points_compiled`."""
    f32 = np.float32
    dz = x * f32(R[0, 2]) + (y * f32(R[1, 2]) + f32(R[2, 2]))
    hit = dz < -1e-6
    if not C[2] > 0:  # a camera below the board plane sees its back: nothing
        hit[...] = False
    # t = −C_z / d_z on hits; elsewhere a huge finite t sends the lookup off the board
    t = np.minimum(dz, f32(-1e-6), out=dz)
    np.divide(f32(-C[2]), t, out=t)
    px = x * f32(R[0, 0]) + (y * f32(R[1, 0]) + f32(R[2, 0]))
    px *= t
    px += f32(C[0])
    py = x * f32(R[0, 1]) + (y * f32(R[1, 1]) + f32(R[2, 1]))
    py *= t
    py += f32(C[1])
    mx = px * f32(inv) + f32(origin[0])
    my = py * f32(-inv) + f32(origin[1])
    return px, py, hit, mx, my


def _board_points_loop(x, y, r, c, above, inv, ox, oy, px, py, hit, mx, my):
    """:func:`board_points_numpy` per pixel (compiled by numba: the same float32 operations in the same order;
    every array flat, one value per pixel; ``r`` the rotation's nine entries and ``c`` the centre, float32)."""
    eps = np.float32(-1e-6)
    mcz = -c[2]
    for i in range(x.size):
        xv = x[i]
        yv = y[i]
        dz = xv * r[2] + (yv * r[5] + r[8])
        hit[i] = above and dz < eps
        t = mcz / (dz if not dz >= eps else eps)  # np.minimum(dz, eps), NaN included
        u = (xv * r[0] + (yv * r[3] + r[6])) * t + c[0]
        v = (xv * r[1] + (yv * r[4] + r[7])) * t + c[1]
        px[i] = u
        py[i] = v
        mx[i] = u * inv + ox
        my[i] = v * -inv + oy


@functools.lru_cache(maxsize=1)
def _board_points_kernel():
    import numba

    return serialized(numba.njit(cache=True, nogil=True, error_model="numpy")(_board_points_loop))


def board_points_compiled(x, y, R, C, inv, origin):
    """:func:`board_points_numpy` in one numba pass over the pixels: the same numbers bit for bit."""
    f32 = np.float32
    shape = np.broadcast_shapes(x.shape, y.shape)
    x, y = (np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1) for a in (x, y))
    px, py, mx, my = (np.empty(shape, dtype=f32) for _ in range(4))
    hit = np.empty(shape, dtype=bool)
    _board_points_kernel()(x, y, np.ascontiguousarray(R, dtype=f32).reshape(-1), np.asarray(C, dtype=f32),
                           bool(C[2] > 0), f32(inv), f32(origin[0]), f32(origin[1]),
                           *(a.reshape(-1) for a in (px, py, hit, mx, my)))
    return px, py, hit, mx, my


# the numba kernels each compiled path calls (sim.compiled.pick asks whether another process is compiling them)
shade_board_compiled.kernels = lambda: (_shade_board_kernel(),)
board_points_compiled.kernels = lambda: (_board_points_kernel(),)


@functools.lru_cache(maxsize=8)
def sensor_pattern(seed: int, shape: tuple, spread: float) -> np.ndarray:
    """A fixed pattern of the sensor, ``max(1 + spread · z, 0)`` per value with ``z`` standard normal from the constant
    ``seed`` (DSNU, PRNU: :class:`SensorModel`), float32, read-only. Made once per process for each sensor and frame
    shape (every session of a process sees the same sensor: ~5 ms a 320 × 240 frame)."""
    z = np.random.default_rng(seed).standard_normal(shape)
    pattern = np.maximum(1.0 + spread * z, 0.0).astype(np.float32)
    pattern.flags.writeable = False
    return pattern


@functools.lru_cache(maxsize=4)
def board_texture(charuco, texel: float, white: float, black: float) -> np.ndarray:
    """The ChArUco board's albedo at ``texel`` metres per texel (``black`` on the markers and black squares,
    ``white`` elsewhere; OpenCV's ``generateImage`` without margin), float32, read-only. Made once per process for
    each board: every simulated camera of a session, and every session of a process (a test run, a benchmark), looks
    at the same board (~1100 × 850 texels: ~10 ms)."""
    w, h = charuco.size
    size = (int(round(w / texel)), int(round(h / texel)))
    img = charuco.board().generateImage(size, marginSize=0, borderBits=1)
    tex = (black + (white - black) * (img / 255.0)).astype(np.float32)
    tex.flags.writeable = False
    return tex


@functools.lru_cache(maxsize=16)
def blurred_board_texture(charuco, texel: float, white: float, black: float, sigma: float) -> np.ndarray:
    """:func:`board_texture` prefiltered with a Gaussian of ``sigma`` texels (``cv2.GaussianBlur``; the pixel
    footprint's prefilter, :meth:`SimCamera._board_view`), float32, read-only; made once per process for each
    board and ``sigma`` (~5 ms each; a rig's camera stays at one distance from the board)."""
    import cv2

    tex = cv2.GaussianBlur(board_texture(charuco, texel, white, black), (0, 0), sigma)
    tex.flags.writeable = False
    return tex


@dataclass(frozen=True)
class SensorModel:
    """Linear sensor (EMVA 1288 model) with an optional 8-bit gamma response.

    Attributes
    ----------
    bit_depth : int
        8, 10, 12, 14 or 16 bits per value.
    full_well : float
        Electrons at which the pixel saturates.
    dn_per_electron : float or None
        System gain K at analogue gain 1; default maps the full well to ~95 % of the range.
    read_noise_e, dark_current_e : float
        Read noise (electrons rms) and dark current (electrons per second at ``dark_ref_c``).
    dark_doubling_c, dark_ref_c : float
        The dark current doubles every ``dark_doubling_c`` kelvin of sensor temperature above
        ``dark_ref_c`` (EMVA Standard 1288 R4.0, 2021, §"Temperature dependency of the dark current":
        ``μ_I(T) = μ_I,ref · 2^((T − T_ref)/T_d)``; typical CMOS sensors 6–8 K).
    dsnu : float
        Dark signal non-uniformity: each pixel's dark current is ``1 + dsnu · z`` (z standard normal,
        clipped at 0) times the mean, a fixed pattern of the sensor (EMVA 1288 §"DSNU").
    prnu : float
        Photo response non-uniformity: each pixel's responsivity is ``1 + prnu · z`` (z standard normal, a
        fixed pattern from its own constant seed) times the mean (EMVA 1288 §"PRNU"); 0: uniform.
    ambient_c, heating_c, thermal_tau : float
        Sensor temperature ``T(t) = ambient + heating · (1 − exp(−t/τ))`` after power-on (first-order
        self-heating of the camera housing, Newton's law of cooling); 0 heating: constant ``ambient``.
    reports_temperature : bool
        Frames carry the sensor temperature (``meta["sensor_temp_c"]``, 0.1 °C steps), as cameras with a
        GenICam ``DeviceTemperature`` feature do.
    black_level : float or None
        Pedestal in DN; default 2^(bits−6) for linear sensors, 0 for 8-bit gamma.
    responsivity : 3 floats
        Electrons per second per unit radiance (W m⁻² sr⁻¹), per RGB channel (lens + QE + filters).
    linear : bool
        False for an 8-bit camera with the response ``y = 255 (x / x_sat)^(1/gamma)``.
    readout : float
        Seconds of readout + transfer after each exposure (lab time a capture costs beyond the
        exposure; :data:`gonio.plan.plan.CaptureSettings.readout` assumes the same 0.05 s).
    """

    bit_depth: int = 12
    full_well: float = 20000.0
    dn_per_electron: float | None = None
    read_noise_e: float = 3.0
    dark_current_e: float = 20.0
    dark_doubling_c: float = 6.5
    dark_ref_c: float = 25.0
    dsnu: float = 0.0
    prnu: float = 0.0
    ambient_c: float = 25.0
    heating_c: float = 0.0
    thermal_tau: float = 1200.0
    reports_temperature: bool = True
    black_level: float | None = None
    responsivity: tuple[float, float, float] = (3.0e6, 3.4e6, 2.6e6)
    linear: bool = True
    gamma: float = 2.2
    min_exposure: float = 1e-5
    max_exposure: float = 2.0
    readout: float = 0.05

    def __post_init__(self):
        if self.bit_depth not in (8, 10, 12, 14, 16):
            raise ConfigError.field(None, "sensor.bit_depth", self.bit_depth, "must be 8, 10, 12, 14 or 16")
        if not self.linear and self.bit_depth != 8:
            raise ConfigError.field(None, "sensor.linear", self.linear, "a non-linear response needs bit_depth 8")
        if self.dn_per_electron is None:
            object.__setattr__(self, "dn_per_electron", 0.95 * (2 ** self.bit_depth) / self.full_well)
        if self.black_level is None:
            object.__setattr__(self, "black_level", float(2 ** (self.bit_depth - 6)) if self.linear else 0.0)

    def temperature(self, t_on: float) -> float:
        """Sensor temperature (°C) ``t_on`` seconds after power-on (see the class docstring)."""
        if self.heating_c == 0.0:
            return self.ambient_c
        return self.ambient_c + self.heating_c * (1.0 - float(np.exp(-max(t_on, 0.0) / self.thermal_tau)))

    def dark_rate(self, temperature: float) -> float:
        """Mean dark current (electrons per second) at ``temperature`` (°C), EMVA 1288's doubling law."""
        return self.dark_current_e * 2.0 ** ((temperature - self.dark_ref_c) / self.dark_doubling_c)

    @property
    def saturation(self) -> int:
        return (1 << self.bit_depth) - 1

    def noise_model(self) -> NoiseModel:
        """The noise model the pipeline should use for this sensor."""
        return NoiseModel(dn_per_electron=float(self.dn_per_electron), read_noise_e=self.read_noise_e,
                          full_well_e=self.full_well)


@dataclass(frozen=True)
class SimScene:
    """What is on the sample stage and how the light shines on it.

    ``light_intensity`` is the radiant intensity (W/sr) of the point source at output 1;
    ``sample_transform`` (4×4, optional) is the sample patch's *true* placement off the board plane
    (a tilt, a mounting error); its normals are transformed by the inverse-transpose. Without it the
    patch sits where the layout declares it (``layout.mount``); give both to simulate a mount that
    differs from what the lab declared.
    """

    layout: TargetLayout
    material: BRDF
    light_intensity: float = 1.0
    board_white: float = 0.8
    board_black: float = 0.03
    background: float = 0.02
    sample_transform: np.ndarray | None = None
    texel: float = 0.25e-3
    #: a glossy black tile or mirror in place of the sample (:class:`sim.mirror_tile.CalibrationTile`): the
    #: geometric calibration's view of the light's reflection; None: the sample patch
    tile: object = None
    #: a sphere coated with the material (:class:`gonio.sphere.Sphere`) in place of the flat patch: rendered with
    #: ``sphere_supersample``² rays per pixel (the pixel's footprint of normals), its shadow on the board
    sphere: object = None
    sphere_supersample: int = 4
    #: electrons per second per pixel (every channel) of a uniform irradiance over the whole sensor at light
    #: output 1 — EMVA 1288's set-up (a diffuse, uniform light source; R4.0 §6): the board, sample and light
    #: position play no part. None: the rendered scene
    flat_field: float | None = None


class SceneLight:
    """The light and reference photodiode of the rig, driven directly (no serial link).

    A stand-in for the light half of the controller emulator, for camera/pipeline tests that run
    before ``sim/rig.py`` wires the emulator: ``set_light``/``read_photodiode`` as in
    :class:`gonio.rig.interfaces.RigController`. Warm-up drift:
    ``output(t) = level · (1 − drift · exp(−t / tau))``.
    """

    def __init__(self, clock: Clock, *, drift: float = 0.0, tau: float = 300.0, pd_noise: float = 0.0,
                 seed: int = 0):
        self.clock = clock
        self.drift = drift
        self.tau = tau
        self.pd_noise = pd_noise
        self._rng = np.random.default_rng(seed)
        self._on = True
        self._level = 1.0

    def set_light(self, on: bool, level: float = 1.0) -> None:
        self._on = bool(on)
        self._level = float(level)

    def output(self) -> float:
        """Relative output now (0 when off)."""
        if not self._on:
            return 0.0
        return self._level * (1.0 - self.drift * np.exp(-self.clock.now() / self.tau))

    def read_photodiode(self, samples: int = 1) -> PhotodiodeReading:
        sigma = self.pd_noise / np.sqrt(max(samples, 1))
        now = self.clock.now()
        return PhotodiodeReading(self.output() + (self._rng.normal(0.0, sigma) if sigma > 0 else 0.0), sigma,
                                 samples=samples, time=now, uptime=now, span=0.0)


class SimCamera:
    """A rendering camera implementing :class:`gonio.rig.interfaces.Camera`.

    Parameters
    ----------
    calibration : CameraCalibration
        Intrinsics used to render (the truth; the pipeline may be given a perturbed copy).
    sensor : SensorModel
    scene : SimScene
    seed : int
        Seed of the noise generator: the same seed and call sequence give identical frames.
    clock : Clock, optional
        Timestamps frames; ``capture`` sleeps the exposure time on it.
    light_output : callable, optional
        Returns the light's relative output now (0 = off); default: :meth:`set_light` state.
    """

    def __init__(self, calibration: CameraCalibration, sensor: SensorModel, scene: SimScene, *, seed: int = 0,
                 clock: Clock | None = None, light_output: Callable[[], float] | None = None):
        self.calibration = calibration
        self.sensor = sensor
        self._scene = scene
        self.clock = clock
        self._rng = np.random.default_rng(seed)
        self._light_output = light_output
        self._on, self._level = True, 1.0
        self._pose = CameraPose.look_at([0.0, 0.0, 0.6])
        self._light_pos = np.array([0.0, 0.3, 0.5])
        self._cache_key: bytes | None = None
        self._rate: np.ndarray | None = None
        self._rays: np.ndarray | None = None
        # per camera pose (and scene): the board's view and the sample's (see _board_view, _sample_view)
        self._view_key: bytes | None = None
        self._view_scene = self._view = None
        self._sample_key: bytes | None = None
        self._sample_scene = self._sample_cached = None
        # per scene: the sample patch's placement (see _patch)
        self._patch_scene = self._patch_cached = None
        self._closed = False
        self._t_power = clock.now() if clock is not None else 0.0  #: power-on: the sensor starts at ambient
        self._zero: np.ndarray | None = None  #: the electron rate of a light-off frame (:meth:`_no_light`)
        self._low = sensor_noise.LowValues()  #: a dark set's values below the Poisson threshold, per exposure

    @property
    def scene(self) -> SimScene:
        """What the camera looks at; setting another one drops everything rendered from the old one (the board
        texture, the electron rates: a scene is frozen, so a new scene is the only way it changes)."""
        return self._scene

    @scene.setter
    def scene(self, scene: SimScene) -> None:
        self._scene = scene
        self._cache_key, self._rate = None, None

    def reseed(self, seed) -> None:
        """Restart the noise generator from ``seed`` (anything ``numpy.random.default_rng`` takes, e.g.
        ``[session seed, pose index]``): the frames that follow depend only on the seed and the calls."""
        self._rng = np.random.default_rng(seed)

    # -- what the rig wiring sets per pose ------------------------------------------------------
    def set_pose(self, pose: CameraPose) -> None:
        """Place the camera (world = sample frame)."""
        self._pose = pose

    def set_light(self, position=None, *, on: bool | None = None, output: float | None = None) -> None:
        """Move the point light (sample frame, metres) and/or switch it / set its relative output."""
        if position is not None:
            p = np.asarray(position, dtype=np.float64)
            if p.shape != (3,) or not np.isfinite(p).all():
                raise ConfigError.field(None, "light.position", position, "needs 3 finite numbers (metres)")
            self._light_pos = p
        if on is not None:
            self._on = bool(on)
        if output is not None:
            self._level = float(output)

    def light_level(self) -> float:
        """The relative light output the next frame sees."""
        if self._light_output is not None:
            return float(self._light_output())
        return self._level if self._on else 0.0

    def sensor_temperature(self) -> float:
        """The sensor's temperature now (°C, :meth:`SensorModel.temperature`)."""
        return self.sensor.temperature((self.clock.now() if self.clock is not None else 0.0) - self._t_power)

    def _dark_pattern(self, shape) -> np.ndarray | None:
        """Relative dark current of every pixel (DSNU), a fixed pattern of the sensor: drawn once from a
        constant seed, not from the session's (the same sensor in every session); None without DSNU."""
        if self.sensor.dsnu <= 0.0:
            return None
        return sensor_pattern(0x5E750, tuple(shape), float(self.sensor.dsnu))

    # -- rendering ------------------------------------------------------------------------------
    def _ray_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalized image coordinates ``(x, y)`` of every pixel centre (cached): the camera
        ray through a pixel is ``(x, y, 1)`` (unnormalized). For an ideal pinhole without skew ``x``
        depends on the column only and ``y`` on the row only: shapes (1, W) and (H, 1), broadcasting."""
        if self._rays is None:
            c = self.calibration
            if not np.any(c.dist) and c.K[0, 1] == 0.0:
                x = ((np.arange(c.width) - c.K[0, 2]) / c.K[0, 0])[None, :]
                y = ((np.arange(c.height) - c.K[1, 2]) / c.K[1, 1])[:, None]
            else:
                v, u = np.mgrid[0:c.height, 0:c.width].astype(np.float64)
                r = c.rays(u, v)
                x, y = r[..., 0] / r[..., 2], r[..., 1] / r[..., 2]
            self._rays = (x, y)
        return self._rays

    def _world_rays(self, box: tuple[slice, slice]) -> np.ndarray:
        """World directions ``Rᵀ (x, y, 1)`` (unnormalized, float64) of the pixels in ``box``."""
        x, y = self._ray_maps()
        rows, cols = box
        xb = x[:, cols] if x.shape[0] == 1 else x[rows, cols]
        yb = y[rows, :] if y.shape[1] == 1 else y[rows, cols]
        xb, yb = np.broadcast_arrays(xb, yb)
        return np.stack([xb, yb, np.ones_like(xb)], axis=-1) @ self._pose.R

    def _texture_key(self) -> tuple:
        """What the board texture depends on (the scene's board, texel and albedos): the key of the process-wide
        caches :func:`board_texture` and :func:`blurred_board_texture`."""
        s = self.scene
        return s.layout.charuco, float(s.texel), float(s.board_white), float(s.board_black)

    def _board_texture(self):
        """The board texture (:func:`board_texture`, made once per process for each board)."""
        return board_texture(*self._texture_key())

    def _prnu_pattern(self, shape) -> np.ndarray | None:
        """Relative responsivity of every pixel (PRNU), a fixed pattern of the sensor drawn from a constant seed;
        None without PRNU."""
        if self.sensor.prnu <= 0.0:
            return None
        return sensor_pattern(0x9E5A, tuple(shape), float(self.sensor.prnu))

    def electron_rate(self) -> np.ndarray:
        """Noiseless electrons per second per pixel at light output 1, shape (H, W, 3), float32 (cached)."""
        flat = self.scene.flat_field
        if flat is not None:  # a uniform irradiance (SimScene.flat_field), through the sensor's PRNU
            c = self.calibration
            if self._rate is None or self._cache_key != ("flat", flat):
                rate = np.full((c.height, c.width, 3), flat, dtype=np.float32)
                prnu = self._prnu_pattern((c.height, c.width))
                self._rate = rate if prnu is None else rate * prnu[..., None]
                self._cache_key = ("flat", flat)
            return self._rate
        key = self._pose.R.tobytes() + self._pose.t.tobytes() + self._light_pos.tobytes()
        if key != self._cache_key:
            self._rate = self._render()
            self._cache_key = key
        return self._rate

    def _blurred_texture(self, sigma: float) -> np.ndarray:
        """The board texture prefiltered with a Gaussian of ``sigma`` texels (:func:`blurred_board_texture`, made
        once per process for each board and ``sigma``: a rig's camera stays at one distance from the board, so a
        session uses one or two values)."""
        return blurred_board_texture(*self._texture_key(), float(sigma))

    def _board_view(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the camera pose alone decides (cached per pose; a plan often moves only the light):
        the board-plane point ``(px, py)`` each pixel's ray meets, whether it meets it (``hit``) and the
        board / background albedo there, all float32 (H, W) and read-only.

        The points: :func:`board_points_numpy` (or its compiled twin); the albedo is a bilinear lookup in the
        texture prefiltered to the pixel footprint."""
        import cv2

        key = self._pose.R.tobytes() + self._pose.t.tobytes()
        if self._view_key == key and self._view_scene is self.scene:
            return self._view
        s, c = self.scene, self.calibration
        C = self._pose.centre
        x, y = (a.astype(np.float32) for a in self._ray_maps())
        w, h = s.layout.charuco.size
        inv = 1.0 / s.texel
        points = compiled.pick(board_points_compiled, board_points_numpy)
        px, py, hit, mx, my = points(x, y, self._pose.R, C, inv, (w / 2 * inv - 0.5, h / 2 * inv - 0.5))
        tex = self._board_texture()
        footprint = np.linalg.norm(C) / c.K[0, 0] / s.texel  # texels per pixel at the board centre
        if footprint > 1.0:
            tex = self._blurred_texture(0.5 * footprint)
        albedo = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=s.background)
        for a in (px, py, hit, albedo):
            a.flags.writeable = False
        self._view_key, self._view_scene, self._view = key, self.scene, (px, py, hit, albedo)
        return self._view

    def _render(self) -> np.ndarray:
        """Radiance L = f(wi, wo) · I · cos θi / r² per pixel (point source; lecture notes 004,
        "point light": E = I cos θ / r²; reflected radiance L = f E), times the responsivity.

        The board (Lambertian, textured, :meth:`_board_view`) is shaded over the whole frame in float32;
        the white patch and the sample only inside the bounding boxes of their projections, in float64.
        """
        s = self.scene
        C = self._pose.centre
        f32 = np.float32
        px, py, hit, albedo = self._board_view()
        S_ = self._light_pos
        shade = compiled.pick(shade_board_compiled, shade_board_numpy)
        irr, rate = shade(px, py, hit, albedo, f32(S_[0]), f32(S_[1]), f32(S_[2] ** 2),
                          f32(s.light_intensity * max(S_[2], 0.0)),
                          np.asarray(self.sensor.responsivity, dtype=np.float32) / f32(np.pi))
        lay = s.layout
        box = self._bbox(lay.white.corners())
        if box is not None:
            sub = (px[box], py[box])
            m = lay.white.contains(*sub) & hit[box]
            wrate = (np.asarray(lay.white_albedo) / np.pi * np.asarray(self.sensor.responsivity)).astype(np.float32)
            rate[box][m] = irr[box][m][:, None] * wrate
        if s.tile is not None:
            from sim.mirror_tile import shade_tile

            shade_tile(self, rate, C)
        elif s.sphere is not None:
            from sim.sphere import shade_sphere

            shade_sphere(self, rate, px, py, hit)
        else:
            self._shade_sample(rate, C)
        return rate

    def _bbox(self, corners: np.ndarray) -> tuple[slice, slice] | None:
        """Pixel box (rows, cols) of the projection of world points, padded by 2 px; None if not in view."""
        c = self.calibration
        pc = corners @ self._pose.R.T + self._pose.t
        if (pc[:, 2] <= 0).any():
            return (slice(0, c.height), slice(0, c.width))
        uv = self._pose.project(corners, c)
        c0, r0 = np.floor(uv.min(axis=0)).astype(int) - 2
        c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + 3
        rows = slice(min(max(int(r0), 0), c.height), min(max(int(r1), 0), c.height))
        cols = slice(min(max(int(c0), 0), c.width), min(max(int(c1), 0), c.width))
        if rows.stop <= rows.start or cols.stop <= cols.start:
            return None
        return rows, cols

    def _patch(self):
        """What the scene alone decides about the sample patch (cached per scene: a session renders one scene from
        hundreds of poses): its placement ``M`` (4×4), its corners in the sample frame, its surface frame
        ``(origin, normal, frame)`` (:func:`gonio.pipeline.target.surface_frame`) and ``M⁻¹``."""
        s = self.scene
        if self._patch_scene is not s:
            M = s.layout.mount.transform if s.sample_transform is None else np.asarray(s.sample_transform,
                                                                                      dtype=np.float64)
            corners = s.layout.sample.corners() @ M[:3, :3].T + M[:3, 3]
            # the normal by the inverse-transpose (lecture notes 000)
            self._patch_cached = (M, corners, *surface_frame(M), np.linalg.inv(M))
            self._patch_scene = s
        return self._patch_cached

    def _sample_view(self, C: np.ndarray):
        """What the camera pose alone decides about the sample patch (cached per pose): its pixel box,
        the pixels inside it that see the patch, the points they see (sample frame) and the local
        outgoing directions there; None when the patch is not in view."""
        s = self.scene
        key = self._pose.R.tobytes() + self._pose.t.tobytes()
        if self._sample_key == key and self._sample_scene is s:
            return self._sample_cached
        M, corners, origin, n, frame, Minv = self._patch()
        view = None
        box = self._bbox(corners)
        if box is not None:
            d = self._world_rays(box)
            dn = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.dot(origin - C, n) / dn
            ok = np.isfinite(t) & (t > 0) & (dn < 0)
            p = C + np.where(ok, t, 0.0)[..., None] * d
            q = p @ Minv[:3, :3].T + Minv[:3, 3]  # back to the patch's own coordinates
            inside = ok & s.layout.sample.contains(q[..., 0], q[..., 1])
            if inside.any():
                pi = p[inside]
                view = (box, inside, pi, to_local(normalize(C - pi), frame), frame)
        self._sample_key, self._sample_scene, self._sample_cached = key, s, view
        return view

    def _shade_sample(self, rate: np.ndarray, C: np.ndarray) -> None:
        """Overwrite ``rate`` where rays hit the (possibly transformed) sample patch."""
        s = self.scene
        view = self._sample_view(C)
        if view is None:
            return
        box, inside, pi, wo, frame = view
        to_light = self._light_pos - pi
        r2 = dot(to_light, to_light)
        wi_w = to_light / np.sqrt(r2)[:, None]
        wi = to_local(wi_w, frame)
        f = s.material.eval(wi, wo)
        irr = s.light_intensity * np.maximum(wi[:, 2], 0.0) / r2
        rate[box][inside] = (f * irr[:, None] * np.asarray(self.sensor.responsivity)).astype(np.float32)

    # -- the Camera protocol --------------------------------------------------------------------
    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        """Render one noisy frame (EMVA 1288 sensor model, see :class:`SensorModel`)."""
        if self._closed:
            raise HardwareError("sim camera: capture after close", device="sim-camera")
        sn = self.sensor
        if not (sn.min_exposure <= exposure <= sn.max_exposure):
            raise ConfigError.field(None, "camera.exposure", exposure,
                                    f"must be in [{sn.min_exposure:g}, {sn.max_exposure:g}] s")
        if not (1.0 <= gain <= 64.0):
            raise ConfigError.field(None, "camera.gain", gain, "must be in [1, 64]")
        level = self.light_level()
        t0 = self.clock.now() if self.clock is not None else 0.0
        temp = self.sensor_temperature()
        dark_e = np.float32(sn.dark_rate(temp) * exposure)
        scale = np.float32(level * exposure)
        # light off: the electrons are the dark signal alone (rate · 0 = 0 for any finite rate), nothing is rendered
        rate = self._no_light() if scale == 0 else self.electron_rate()
        pattern = self._dark_pattern(rate.shape)
        if sn.linear:
            kw = {}
            expose = compiled.pick(sensor_noise.expose_compiled, sensor_noise.expose_numpy)
            if expose is sensor_noise.expose_compiled and scale == 0:
                # a dark set's frames at one exposure have the same means: gathered once (the DSNU pattern is made
                # once per frame shape: its id and the shape name it)
                kw = dict(memo=self._low, key=(float(dark_e), id(pattern), rate.shape, sn.dsnu), dark=True)
            pixels = expose(
                rate, scale, pattern, dark_e, self._rng, self._normal_indices, normal_table(), POISSON_EXACT_BELOW,
                read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron * gain,
                black=sn.black_level, saturation=sn.saturation, dtype=np.uint8 if sn.bit_depth == 8 else np.uint16,
                **kw)
        else:
            mean_e = sensor_noise.means_numpy(rate, scale, pattern, dark_e)
            draws = sensor_noise.draw(self._rng, self._normal_indices, mean_e, POISSON_EXACT_BELOW)
            e = sensor_noise.electrons_numpy(mean_e, normal_table(), *draws, read_noise=sn.read_noise_e)
            np.minimum(e, np.float32(sn.full_well), out=e)
            x = np.clip(e * np.float32(gain / sn.full_well), 0.0, 1.0)
            dn = 255.0 * x ** np.float32(1.0 / sn.gamma)
            np.rint(dn, out=dn)
            np.clip(dn, 0, sn.saturation, out=dn)
            pixels = dn.astype(np.uint8)
        if self.clock is not None:
            self.clock.sleep(exposure + sn.readout)
        return Frame(pixels=pixels, exposure=float(exposure), gain=float(gain), bit_depth=sn.bit_depth,
                     black_level=float(sn.black_level), timestamp=t0, linear=sn.linear,
                     meta={"device": "sim", "light_output": level,
                           **({"sensor_temp_c": round(temp, 1)} if sn.reports_temperature else {})})

    def _no_light(self) -> np.ndarray:
        """The electron rate of a frame with the light off, zero everywhere (H, W, 3), float32, read-only (cached):
        its means are the dark signal alone, as a rendered rate times the zero light output makes them (bit for bit:
        x · 0 + d = d for any finite x), without rendering the scene."""
        c = self.calibration
        shape = (c.height, c.width, 3)
        if self._zero is None or self._zero.shape != shape:
            self._zero = np.zeros(shape, dtype=np.float32)
            self._zero.flags.writeable = False
        return self._zero

    def _normal_indices(self, shape) -> np.ndarray:
        """Uniform 16-bit integers of ``shape``: ``Generator.integers(0, 2¹⁶, dtype=uint16)``'s, the indices of
        the standard normal deviates looked up in :func:`normal_table` (~3× faster than NumPy's float32
        ziggurat for a full frame, with the same mean and variance; the tails are cut at ±4.3σ, probability
        ~2·10⁻⁵ per value).

        That call splits each 64-bit output of the bit generator into 32-bit halves and those into 16-bit
        halves, low first, one value at a time. When the count is a multiple of four and no 32-bit half is
        pending in the bit generator, the same numbers are the raw outputs' four 16-bit fields (``random_raw``
        viewed little-endian), ~10× cheaper; otherwise that call itself. Either way the same numbers and the
        same generator state after."""
        n = int(np.prod(shape))
        bg = self._rng.bit_generator
        if isinstance(bg, np.random.PCG64) and n % 4 == 0 and not bg.state["has_uint32"]:
            raw = bg.random_raw(n // 4).astype("<u8", copy=False)  # the same fields on any byte order
            return raw.view("<u2").reshape(shape)
        return self._rng.integers(0, 1 << 16, size=shape, dtype=np.uint16)

    def close(self) -> None:
        self._closed = True
