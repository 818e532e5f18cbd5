"""One pose, end to end: meter, pick a bracket, capture, subtract darks, merge, locate, compute samples.

The session runner calls :meth:`Pipeline.measure` once per pose with the light position from the
kinematics (sample frame); the camera pose comes from the ChArUco board in the frame (or, flagged
``NO_BOARD``, from the kinematics' hint when the board is not found).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gonio import samples as S
from gonio.errors import ConfigError, DataError, HardwareError
from gonio.pipeline.dark import DarkCache
from gonio.pipeline.exposure import CapturePlan, ExposureSettings, plan_bracket
from gonio.pipeline.hdr import BadFrame, SATURATION_MARGIN, average_frames, check_frame, merge_linear
from gonio.pipeline.covers import cover_points
from gonio.pipeline.markers import BoardPose, board_poses_agree, detect_board_pose, refine_board_pose, to_gray8
from gonio.pipeline.signal import SignalCheck
from gonio.pipeline.reflectance import build_roi, used_pixel_samples
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from gonio.rig.interfaces import Camera, Clock, Frame
from gonio.samples import SampleSet

__all__ = ["PipelineSettings", "PoseResult", "BoardNotFound", "Pipeline"]


#: A metering frame whose ChArUco search failed is taken again at another exposure only if that exposure
#: differs from this one by at least this factor. The detector sees :func:`~gonio.pipeline.markers.to_gray8`'s
#: image, stretched to the frame's 99th percentile, so a closer exposure shows the board with the same
#: contrast and at most √1.5 ≈ 1.22× the shot-noise SNR: not a better view, a reshoot hoping for luckier noise
#: (the frames and the lab time of up to ``meter_tries`` such reshoots at a pose whose board is out of sight).
BOARD_REMETER_FACTOR = 1.5
#: pixels merged around a sphere's projected box: room for its silhouette's edge search (gonio.sphere.refine)
SPHERE_PAD_PX = 10
#: a sphere's bracket: the pixels a MERL cell averages (its samples from this frame and the frames of neighbouring
#: light positions), so a pixel's SNR target is the sample target over √4 (150 at the default 300)
SPHERE_PIXELS_PER_CELL = 4


def _used_index(roi, used: np.ndarray, width: int) -> np.ndarray:
    """Flat indices, into a frame ``width`` pixels wide, of the ROI box's pixels ``used`` (an (h, w) mask), in
    the box's C order: ``_take(img, index)`` is ``img[roi.region][used]``, the same values in the same order."""
    r, c = np.nonzero(used)
    return (r + roi.rows.start) * width + (c + roi.cols.start)


def _take(img: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The pixels ``index`` (:func:`_used_index`) of an (H, W, C) image, (n, C): a gather of the flattened frame
    (a copy)."""
    return np.take(img.reshape(-1, img.shape[-1]), index, axis=0)


class BoardNotFound(HardwareError):
    """The ChArUco board is not visible and no kinematic camera pose was given."""


@dataclass(frozen=True)
class PipelineSettings:
    """Knobs of :class:`Pipeline` (defaults are the benchmarked ones, benchmarks/bench_pipeline.py)."""

    exposure: ExposureSettings = field(default_factory=ExposureSettings)
    initial_exposure: float = 0.01
    gain: float = 1.0
    meter_tries: int = 6
    max_bin_deg: float = 2.0
    max_bins: int = 8
    margin_px: float = 3.0
    min_snr: float = 10.0
    drift_tolerance: float = 0.02
    dark_frames: int = 4
    dark_max_age: float = 900.0
    retries: int = 2
    light_level: float = 1.0
    #: Standard uncertainty (metres, per coordinate) of the light position the caller passes: the
    #: light arm's positioning error. Default: the default rig (0.6 m arm, 4096-tick encoders, ~0.3
    #: tick rms reading noise plus ~1 tick of backlash) puts the source within ~0.4 mm rms.
    light_position_sigma: float = 4e-4
    #: Propagate the ChArUco pose's covariance into the samples' uncertainty.
    pose_uncertainty: bool = True
    #: A sphere's (or cylinder's) bracket: at most this many frames per exposure. One HDR frame per light position,
    #: as the image-based rigs take them (Marschner et al. 1999; Matusik et al. 2003): a MERL cell's value averages
    #: the pixels of many frames, so the lab time buys more light positions (cells) rather than repeated frames of
    #: one — a frame costs its readout (50 ms) whatever its exposure. Each pixel's σ is its own (noise model), so
    #: the cells' σ stay honest (benchmarks sphere measures the truth within 2σ).
    sphere_max_frames: int = 1


@dataclass
class PoseResult:
    """Samples of one pose and how they were obtained."""

    samples: SampleSet
    plan: CapturePlan
    board: BoardPose | None
    camera_pose: CameraPose
    light: list[float]
    #: when each ``light`` reading was taken (:class:`gonio.rig.interfaces.PhotodiodeReading`): the host
    #: clock's time, the controller's uptime and the sampling span, seconds (None where not known)
    light_times: list[tuple] = field(default_factory=list)
    #: how ``board`` was obtained: ``"detected"`` in this pose's metering frame, ``"reused"`` (the ``board`` the
    #: caller passed: the camera has not moved since, and its corners are where it puts them in this frame),
    #: ``"confirmed"`` (passed, and a detection in this pose's metering frame agreed with it), ``"replaced"``
    #: (passed, but this pose's detection disagreed and was used), ``"unverified"`` (passed and kept, the board
    #: found in this frame neither way), or ``None`` (no board: the kinematic pose)
    board_source: str | None = None
    #: a sphere's pose: its pixels used and rejected (:func:`gonio.sphere.pixels.sphere_frame_samples`); else None
    sphere_counts: dict | None = None
    #: a sphere's pose: its per-pixel samples (:class:`gonio.sphere.pixels.SphereFrameSamples`); else None
    sphere_frame: object = None


class Pipeline:
    """Frames in, calibrated reflectance samples out.

    Parameters
    ----------
    camera : Camera
    calibration : CameraCalibration
    layout : TargetLayout
    light : RigController-like, optional
        ``set_light(on, level)`` for dark frames and ``read_photodiode()`` for drift normalization.
        Without it, darks are the black level only and the light output is taken as 1.
    clock : Clock, optional
        For the dark-frame schedule.
    absolute_scale : 3 floats, optional
        Absolute mode: DN/s at gain 1 per unit (f · I cos θ / r²) at photodiode 1, instead of the white reference.
    """

    def __init__(self, camera: Camera, calibration: CameraCalibration, layout: TargetLayout, *, light=None,
                 clock: Clock | None = None, settings: PipelineSettings | None = None, absolute_scale=None):
        self.camera = camera
        self.calib = calibration
        self.layout = layout
        self.light = light
        self.settings = settings or PipelineSettings()
        self.absolute_scale = absolute_scale
        self.darks = DarkCache(camera, calibration, light=light, clock=clock, n_frames=self.settings.dark_frames,
                               max_age=self.settings.dark_max_age, level=self.settings.light_level,
                               frame_check=self._check_dark, retries=self.settings.retries)
        self._size_checked = False
        self._size_misses, self._miss_shape = 0, None
        self._board = layout.charuco.board()
        self._covers = cover_points(layout)
        self._next_exposure = self.settings.initial_exposure
        self._signal = SignalCheck(calibration.noise, self._limit)
        #: a sphere: the record metas (their ``sphere_centre``) of the poses stored before this one, in pose order —
        #: the runner sets it (:func:`gonio.sphere.pose.sphere_pose_samples` refines the centre from them)
        self.sphere_history: list = []

    def check_frame(self, frame: Frame) -> np.ndarray:
        """:func:`gonio.pipeline.hdr.check_frame`, and until the first frame of the calibrated size (the
        session's first captures: its dark frames) a size check: ``retries + 1`` frames in a row of
        one other size are a :class:`~gonio.errors.ConfigError` naming both sizes, not bad frames to
        retry pose after pose (every pose would fail to find the board)."""
        if not self._size_checked:
            shape = tuple(int(n) for n in np.shape(getattr(frame, "pixels", ()))[:2])
            want = (self.calib.height, self.calib.width)
            if len(shape) == 2 and shape != want:
                # one odd frame may be a transfer glitch (retried as a BadFrame); the same size again
                # and again from the first frame on is the camera's configuration
                self._size_misses = self._size_misses + 1 if shape == self._miss_shape else 1
                self._miss_shape = shape
                if self._size_misses > self.settings.retries:
                    raise ConfigError(f"camera: frame size {shape[1]}x{shape[0]} (width x height) does not match "
                                      f"the calibration's {want[1]}x{want[0]}: recalibrate or set the camera's "
                                      "resolution")
            elif len(shape) == 2:
                self._size_checked = True
        return check_frame(frame, self.calib)

    def _check_dark(self, frame: Frame) -> np.ndarray:
        """:meth:`check_frame` and, for a dark frame, :meth:`SignalCheck.dark_frame` (not stale, not overloaded)."""
        px = self.check_frame(frame)
        self._signal.dark_frame(frame, px)
        return px

    # -- capture helpers ----------------------------------------------------------------------
    def _grab(self, exposure: float, gain: float, *, meter: bool = False, dark=None) -> tuple[Frame, np.ndarray, float, float]:
        """One checked frame, the light output read right after it and that reading's standard
        uncertainty (bounded retries on bad frames; a bracket frame must also show a signal,
        :mod:`gonio.pipeline.signal`; a metering frame (``meter``) only must not repeat the previous one)."""
        last: Exception | None = None
        for _ in range(self.settings.retries + 1):
            frame = self.camera.capture(exposure, gain)
            if not getattr(frame, "linear", True):
                raise BadFrame("camera frame: linear = False: Pipeline merges linear frames only; linearize "
                               "8-bit frames with gonio.pipeline.hdr.calibrate_response first", device="camera")
            try:
                px = self.check_frame(frame)
                self.darks.note(frame)  # the sensor temperature modelled darks follow
                if meter:  # against this exposure's dark frame if the session measured it: black, not dim
                    dark = self.darks.cached(exposure, gain)
                self._signal(frame, px, levels=not meter, dark=dark)  # black, all-saturated, stale: retaken, then flagged
            except BadFrame as exc:
                last = exc
                continue
            if self.light is None:
                return frame, px, 1.0, 0.0
            reading = self.light.read_photodiode()
            level, u = reading
            self._read_at = tuple(getattr(reading, k, None) for k in ("time", "uptime", "span"))
            return frame, px, float(level), float(u)
        raise last  # type: ignore[misc]

    def _limit(self, frame: Frame) -> float:
        return self.calib.noise.linear_limit(frame.saturation_level, frame.black_level, frame.gain)

    @staticmethod
    def _gray(frame: Frame, px: np.ndarray) -> np.ndarray:
        return to_gray8(px, frame.bit_depth if frame.linear else 8, frame.black_level if frame.linear else 0.0)

    def _still(self, frame: Frame, px: np.ndarray, known: BoardPose) -> bool:
        """``known``'s corners are where it puts them in this frame: :func:`refine_board_pose` agrees with it
        (:func:`board_poses_agree`)."""
        found = refine_board_pose(self._gray(frame, px), known, self.calib, self.layout.charuco, self._board)
        return found is not None and board_poses_agree(known, found)

    def _locate(self, frame: Frame, px: np.ndarray, hint: CameraPose | None) -> tuple[BoardPose | None, CameraPose | None]:
        bp = detect_board_pose(self._gray(frame, px), self.calib, self.layout.charuco, self._board, covers=self._covers)
        if bp is not None:
            return bp, bp.pose
        return None, hint

    # -- the pose -----------------------------------------------------------------------------
    def measure(self, light_position, *, pose_index: int = -1, camera_pose_hint: CameraPose | None = None,
                plan: CapturePlan | None = None, nominal=None, meter_exposure: float | None = None,
                board: BoardPose | None = None, confirm_board: bool = False, light_cov=None) -> PoseResult:
        """Measure one pose; see the module docstring. Raises :class:`BoardNotFound` or :class:`BadFrame`.

        ``light_cov``: covariance (m², 3 × 3) of ``light_position`` beyond the servos' own scatter
        (:attr:`PipelineSettings.light_position_sigma`): the geometric calibration's, propagated to this pose
        (:func:`gonio.rig.geocov.light_position_covariance`); both enter every sample's σ and ``sigma_pose``.

        ``nominal = (camera centre, light position)`` of the planned pose fixes the tiling (see
        :func:`gonio.pipeline.reflectance.build_roi`). ``meter_exposure``: exposure of the metering frame
        (default: the previous pose's shortest exposure); a fixed value makes a pose's bracket depend on the
        pose only.

        ``board``: the board pose found at an earlier pose from which the camera has not moved (the caller
        knows: :class:`gonio.session.runner.SessionRunner`), used instead of a search in this pose's metering
        frame once its corners are found again where it puts them (:meth:`_still`: a board or sample holder
        bumped since shows). When they are not, or with ``confirm_board``, the metering frame is searched
        (once, no re-metering) and the given pose kept only if the two agree (:func:`board_poses_agree`);
        else this pose's own is used. The result's ``board_source`` says which: ``reused`` (corners found
        again), ``confirmed``, ``replaced``, or ``unverified`` (the board found in neither way: the given pose
        is kept), ``detected`` without a given pose."""
        st = self.settings
        gain = st.gain if plan is None else plan.gain
        flags = 0
        t = self._next_exposure if meter_exposure is None else float(meter_exposure)
        # 1. meter (and locate the board on the metering frame)
        frame, px, level, _ = self._grab(t, gain, meter=True)
        known, board, cam_pose, source = board, None, None, None
        if known is not None:
            board, cam_pose, source = known, known.pose, "reused"
            if confirm_board or not self._still(frame, px, known):
                found, _ = self._locate(frame, px, None)
                if found is None:
                    source = "unverified"
                elif not board_poses_agree(known, found):
                    board, cam_pose, source = found, found.pose, "replaced"
                else:
                    source = "confirmed"
        for _ in range(0 if known is not None else st.meter_tries):
            board, cam_pose = self._locate(frame, px, camera_pose_hint)
            if board is not None:
                break
            # not found: bring the whole frame's 99th percentile to mid-range and look again
            rng = self._limit(frame) - frame.black_level
            hi = float(np.percentile(px[::4, ::4], 99.0)) - frame.black_level
            factor = float(np.clip(0.5 * rng / max(hi, 1.0), 1 / 64, 64))
            if hi >= (1 - SATURATION_MARGIN) * rng:
                factor = 1 / 8
            t_new = float(np.clip(t * factor, st.exposure.min_exposure, st.exposure.max_exposure))
            if max(t_new / t, t / t_new) < BOARD_REMETER_FACTOR:  # exposed as wanted: this (failed) search stands
                break
            t = t_new
            frame, px, level, _ = self._grab(t, gain, meter=True)
        if source is None and board is not None:
            source = "detected"
        if cam_pose is None:
            raise BoardNotFound("camera frame: ChArUco board not found (fewer than 6 corners) and no kinematic "
                                "camera pose given", device="camera")
        if board is None:
            flags |= S.NO_BOARD
        if self.layout.curved is not None:  # image-based: one sample per pixel of the sphere or cylinder
            return self._measure_sphere(frame, px, level, gain, plan, cam_pose, board, source, flags, light_position,
                                        pose_index)
        roi = build_roi(cam_pose, self.calib, self.layout, light_position, margin_px=st.margin_px,
                        max_bin_deg=st.max_bin_deg, max_bins=st.max_bins, nominal=nominal)
        if roi.empty:
            raise BoardNotFound("camera frame: the sample or white patch is outside the image at this pose",
                                device="camera")
        # only the ROI's sample and white pixels are metered and merged (a quarter of its box, typically): the merge
        # is per pixel, so they get the values a merge of the whole box gives them; the samples come from these alone
        used = _used_index(roi, (roi.label >= 0) | roi.white, self.calib.width)
        if plan is None:
            n_min = max(1, int(np.bincount(roi.label[roi.label >= 0], minlength=roi.n_tiles).min()))
            plan = self._meter(frame, px, level, used, gain, n_min)
        hdr, lights, times, flags = self._capture_merge(plan, used, flags)
        perturb = board.perturbed() if (board is not None and st.pose_uncertainty) else []
        samples = used_pixel_samples(hdr, roi, cam_pose, light_position, self.layout, absolute_scale=self.absolute_scale,
                                     min_snr=st.min_snr, pose_index=pose_index, flags=flags,
                                     pose_perturbations=perturb, light_sigma=self._light_sigma(light_cov))
        self._next_exposure = plan.exposures[0]
        return PoseResult(samples, plan, board, cam_pose, lights, times, source)

    def _light_sigma(self, light_cov):
        """The light position's uncertainty: the servos' per-coordinate σ, plus the calibration's covariance."""
        st = self.settings
        if light_cov is None:
            return st.light_position_sigma
        C = np.asarray(light_cov, dtype=np.float64).reshape(3, 3)
        return C + np.eye(3) * st.light_position_sigma ** 2

    def _capture_merge(self, plan: CapturePlan, used: np.ndarray, flags: int):
        """Capture ``plan``'s bracket, subtract darks and merge the ``used`` pixels (flat indices): ``(hdr as an
        (n, 1, C) image, photodiode readings, their times, flags + DRIFT)``; a light that reads off raises."""
        st = self.settings
        stacks, darks, lights, times = [], [], [], []
        for t_k, n_k in zip(plan.exposures, plan.frames):
            cached = self.darks.cached(t_k, plan.gain)  # the runner measures the dark set before the poses
            grabs = []
            for _ in range(n_k):
                self._read_at = (None, None, None)
                grabs.append(self._grab(t_k, plan.gain, dark=cached))
                times.append(self._read_at)
            d = self.darks.get(t_k, plan.gain)
            lv = [g[2] for g in grabs]
            lights.extend(lv)
            # the used pixels as an (n, 1, C) image: what merge_linear takes
            stacks.append(average_frames([_take(g[1], used)[:, None] for g in grabs], [g[0] for g in grabs], lv,
                                         self._limit(grabs[0][0]), light_u=[g[3] for g in grabs]))
            darks.append((_take(d.mean, used)[:, None].astype(np.float64),
                          _take(d.var, used)[:, None].astype(np.float64)))
        hdr = merge_linear(stacks, darks, self.calib.noise)  # the used pixels' merge: what used_pixel_samples takes
        lv = np.asarray(lights)
        if lv.size and (lv.max() - lv.min()) > st.drift_tolerance * max(lv.mean(), 1e-12):
            flags |= S.DRIFT
        if lv.size and not (lv.min() > 0):
            raise HardwareError(f"light: photodiode reads {lv.min():g}: the light is off or failed", device="light")
        return hdr, lights, times, flags

    def _measure_sphere(self, frame, px, level, gain, plan, cam_pose, board, source, flags, light_position,
                        pose_index) -> PoseResult:
        """One pose of a sphere (image-based acquisition, :mod:`gonio.sphere`): the sphere's and the white
        reference's pixels metered and merged as a flat sample's are, then one sample per sphere pixel
        (:func:`gonio.sphere.pixels.sphere_frame_samples`), wi and wo in each pixel's normal frame; the pose's
        pixel counts (used, silhouette, terminator, saturated, dark) in :attr:`PoseResult.sphere_counts`."""
        from gonio.sphere.pixels import sphere_box, sphere_lit_pixels, white_box
        from gonio.sphere.pose import sphere_pose_samples

        c = self.calib
        sph = self.layout.curved
        box, wbox = sphere_box(c, cam_pose, sph, pad=SPHERE_PAD_PX), white_box(c, cam_pose, self.layout)
        if box is None or wbox is None:
            raise BoardNotFound("camera frame: the sphere or the white patch is outside the image at this pose",
                                device="camera")
        mask = np.zeros((c.height, c.width), dtype=bool)
        mask[box] = True
        mask[wbox] = True
        used = np.flatnonzero(mask)
        if plan is None:  # metered on what gives samples: the sphere's lit, seen pixels and the white patch
            lit = sphere_lit_pixels(c, cam_pose, sph, light_position, box)
            lit[wbox] = True
            plan = self._meter(frame, px, level, np.flatnonzero(lit), gain, SPHERE_PIXELS_PER_CELL, every_pixel=True,
                               max_frames=self.settings.sphere_max_frames)
        hdr, lights, times, flags = self._capture_merge(plan, used, flags)
        C = hdr.rate.shape[-1]
        rate = np.full((c.height * c.width, C), np.nan)
        var = np.full((c.height * c.width, C), np.nan)
        rate[used], var[used] = hdr.rate[:, 0], hdr.var[:, 0]
        try:
            perturb = board.perturbed() if (board is not None and self.settings.pose_uncertainty) else []
            fs = sphere_pose_samples(rate.reshape(c.height, c.width, C), var.reshape(c.height, c.width, C), c,
                                     cam_pose, sph, light_position, self.layout, history=self.sphere_history,
                                     min_snr=self.settings.min_snr, pose_perturbations=perturb)
        except DataError as exc:  # the white reference unusable at this pose: no sample, the pose is skipped
            raise BoardNotFound(f"camera frame: {exc}", device="camera") from None
        n = len(fs.f)
        samples = SampleSet(fs.wi_local, fs.wo_local, fs.f, fs.sigma, n_pixels=np.ones(n), flags=np.full(n, flags),
                            pose=np.full(n, pose_index))
        self._next_exposure = plan.exposures[0]
        counts = dict(fs.counts)
        return PoseResult(samples, plan, board, cam_pose, lights, times, source, sphere_counts=counts, sphere_frame=fs)

    def _meter(self, frame: Frame, px: np.ndarray, level: float, used: np.ndarray, gain: float,
               n_min: int, *, every_pixel: bool = False, max_frames: int | None = None) -> CapturePlan:
        """Find signal rates of the sample and white pixels (``used``: their :func:`_used_index`); re-meter
        (bounded) when saturated or dark. ``n_min``: the fewest pixels a sample averages (the bracket's SNR
        target is per sample). ``every_pixel``: each pixel is a sample (a sphere): the brightest pixel, not the
        99.9th percentile, sets the shortest exposure, and one saturated pixel re-meters (a chrome-like sphere's
        highlight is a pixel or two, and it is the peak of the lobe). ``max_frames``: at most this many frames per
        exposure (:attr:`PipelineSettings.sphere_max_frames`)."""
        q_hi, sat_tol = (100.0, 0.0) if every_pixel else (99.9, 0.001)
        st, es = self.settings, self.settings.exposure
        t = frame.exposure
        for _ in range(st.meter_tries):
            limit = self._limit(frame)
            rng = limit - frame.black_level
            vals = _take(px, used).astype(np.float64) - frame.black_level
            sat = vals >= (1 - SATURATION_MARGIN) * rng
            frac_sat = sat.any(axis=-1).mean()
            bright = float(np.percentile(vals, q_hi))
            if frac_sat > sat_tol and t > es.min_exposure:
                t = max(t / es.step**2, es.min_exposure)
            elif bright < 0.05 * rng and t < es.max_exposure:
                t = min(t * es.step**2, es.max_exposure)
            else:
                break
            frame, px, level, _ = self._grab(t, gain, meter=True)
        scale = frame.exposure * frame.gain * max(level, 1e-12)
        vals = np.maximum(_take(px, used).astype(np.float64) - frame.black_level, 0.5) / scale
        # both percentiles in one call (float64 values: each is the one a call of its own gives)
        hi, lo = (float(v) for v in np.percentile(vals, [q_hi, 2.0]))
        rate_bright = hi * (1.0 if frac_sat <= sat_tol else 4.0)
        rate_dim = lo
        if max_frames is not None:
            es = replace(es, max_frames=max(int(max_frames), 1), min_frames=min(es.min_frames, max(int(max_frames), 1)))
        return plan_bracket(rate_bright, rate_dim, rng, n_min, self.calib.noise, es, gain)
