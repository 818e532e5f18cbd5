"""``gonio camera calibrate|noise``: characterise the camera on the lab's first day and write the ``CAMERA.toml``
the rest of gonio reads (:mod:`gonio.rig.calibration`, written by :mod:`gonio.rig.camera_toml`).

``calibrate``: intrinsics and distortion from ChArUco views (:mod:`gonio.pipeline.intrinsics`) — taken by the
camera on the rig's camera arm (:mod:`gonio.session.camera_views`; ``--sim``: the simulated rig, whose camera
has a principal point off-centre and a distortion the host is not told), or read from image files (``--images``).
``noise``: EMVA 1288 photon transfer (:mod:`gonio.pipeline.emva1288`) on a uniform target — the camera looking
at a diffuse, evenly lit target (on a rig: the light switched by ``--controller-port``); ``--sim``: the
simulated sensor under a uniform irradiance. Both also run on a GenICam camera (``--backend aravis``;
``--sim-camera gige``: the simulated camera served over GigE Vision by Aravis's fake camera).
"""

from __future__ import annotations

import sys

#: The simulated camera as built (``--sim``): principal point offset (px) and distortion (k1, k2, p1, p2, k3).
SIM_PRINCIPAL_OFFSET = "6,-4"
SIM_DISTORTION = "-0.12,0.08,0,0,0"


def register_actions(csub, common) -> None:
    """Add ``calibrate`` and ``noise`` to ``gonio camera``'s subcommands (``common``: its device options)."""
    c = csub.add_parser("calibrate", help="intrinsics + distortion from ChArUco views (on the rig or image files), "
                                          "with each parameter's σ and a coverage check; writes CAMERA.toml")
    where = c.add_mutually_exclusive_group(required=True)
    where.add_argument("--images", nargs="+", metavar="IMAGE", help="image files of the ChArUco board (PNG, TIFF, "
                       "JPEG, .npy; the board moved around a fixed camera, tilted about both axes, into the corners)")
    where.add_argument("--camera", metavar="N|ID", help="the rig's camera (with --rig, --servo-port, "
                                                         "--controller-port): the camera arm carries it around the board")
    where.add_argument("--sim", action="store_true", help="the simulated rig (its camera as built: --sim-principal-"
                                                          "offset, --sim-distortion)")
    c.add_argument("--rig", help="rig file (default with --sim: the shipped rig)")
    c.add_argument("--servo-port")
    c.add_argument("--controller-port")
    c.add_argument("--backend", default="v4l2", help="camera backend (OpenCV name, or aravis)")
    c.add_argument("--pixel-format", default="Mono16", help="aravis: pixel format")
    c.add_argument("--gain-unit", default="dB", choices=("dB", "raw"))
    c.add_argument("--target", metavar="TARGET.toml", help="the ChArUco board ([charuco]); default: gonio's target")
    c.add_argument("--dist-model", default="auto", choices=("auto", "2", "4", "5"),
                   help="distortion coefficients estimated: 2 (k1 k2), 4 (k1 k2 p1 p2), 5 (+ k3); auto (default): 4, "
                        "or 2 when the tangential terms are not significant")
    c.add_argument("--quick", action="store_true", help="on the rig: a third of the views")
    c.add_argument("--sim-resolution", default="320x240", metavar="WxH")
    c.add_argument("--sim-principal-offset", default=SIM_PRINCIPAL_OFFSET, metavar="DX,DY",
                   help=f"the simulated camera's principal point offset from the centre, px (default {SIM_PRINCIPAL_OFFSET})")
    c.add_argument("--sim-distortion", default=SIM_DISTORTION, metavar="K1,K2,P1,P2,K3",
                   help=f"the simulated lens's distortion (default {SIM_DISTORTION})")
    c.add_argument("--sim-camera", default="direct", choices=("direct", "gige"),
                   help="gige: the simulated camera over GigE Vision (Aravis)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("-o", "--output", required=True, metavar="CAMERA.toml")
    c.add_argument("--force", action="store_true", help="update an existing CAMERA.toml (its intrinsics replaced, "
                                                        "everything else kept; the old text kept as .prev)")
    c.set_defaults(func=run_calibrate)

    n = csub.add_parser("noise", help="EMVA 1288 photon transfer on a uniform target: gain, read noise, dark "
                                      "current, DSNU/PRNU, linearity, saturation; writes CAMERA.toml [noise]")
    common(n)
    n.add_argument("--controller-port", help="the rig controller whose light illuminates the target (switched off "
                                             "for the dark frames); required with --camera")
    n.add_argument("--sim-camera", default="direct", choices=("direct", "gige"),
                   help="gige: the simulated camera over GigE Vision (Aravis), in --pixel-format")
    n.add_argument("--steps", type=int, default=50, help="exposure steps from dark to saturation (EMVA 1288: ≥ 50)")
    n.add_argument("--average", type=int, default=16, help="frames averaged for DSNU/PRNU (EMVA 1288: ≥ 16)")
    n.add_argument("--dark-exposures", default="0.1,0.25,0.5", metavar="S,S,...",
                   help="long dark exposures for the dark current, seconds")
    n.add_argument("--channel", default="G", choices=("R", "G", "B"), help="the channel of a colour camera")
    n.add_argument("--gain", type=float, default=1.0, help="analogue gain the camera is characterised at")
    n.add_argument("-o", "--output", required=True, metavar="CAMERA.toml")
    n.add_argument("--force", action="store_true", help="update an existing CAMERA.toml ([noise] and [emva1288] "
                                                        "replaced, everything else kept; the old text kept as .prev)")
    n.set_defaults(func=run_noise, sim_bit_depth=12)


def _floats(text: str, option: str, n: int | None = None, positive: bool = False) -> list[float]:
    import math

    from gonio.errors import ConfigError

    try:
        vals = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        vals = []
    if not vals or (n is not None and len(vals) != n) or not all(math.isfinite(v) for v in vals) \
            or (positive and not all(v > 0 for v in vals)):
        raise ConfigError.field(option, option.lstrip("-"), text, f"expected {n or 'some'} comma-separated "
                                f"{'positive ' if positive else ''}numbers")
    return vals


# -- calibrate -------------------------------------------------------------------------------------------------
def run_calibrate(args) -> int:
    from gonio.session.options import parse_resolution as _resolution
    from gonio.io.outputs import check_output
    from gonio.pipeline.intrinsics import calibrate_intrinsics
    from gonio.pipeline.target import TargetLayout, load_target

    check_output(args.output, option="-o", force=args.force, suffixes=(".toml",))
    from gonio.pipeline.covers import cover_points

    layout = load_target(args.target) if args.target else TargetLayout()
    spec, covers = layout.charuco, cover_points(layout)  # the target's white patch and sample: their corners left out
    truth, camera_table = None, {}
    if args.images:
        from gonio.session.camera_views import views_from_files

        views, refused, (w, h) = views_from_files(args.images, spec, covers)
        how = f"{len(args.images)} image files"
    else:
        views, refused, (w, h), truth, camera_table = _rig_views(args, spec, _resolution(args.sim_resolution), covers)
        how = "the simulated rig's camera arm" if args.sim else f"the camera arm of {args.rig}"
    print(f"ChArUco board found in {len(views)} of {len(views) + len(refused)} views ({how})"
          + (f"; not in e.g. {refused[0][0]}: {refused[0][1]}" if refused else ""))
    res = calibrate_intrinsics(views, w, h, model=args.dist_model)
    print("\n".join(res.lines()))
    if truth is not None:
        print(f"  vs the simulated camera as built: fx {res.K[0, 0] - truth.K[0, 0]:+.3f} px, cx "
              f"{res.K[0, 2] - truth.K[0, 2]:+.3f} px, cy {res.K[1, 2] - truth.K[1, 2]:+.3f} px, k1 "
              f"{res.dist[0] - truth.dist[0]:+.4f}")
    _write_intrinsics(args, res, camera_table, how)
    return 0


def _rig_views(args, spec, size, covers=None):
    """Views taken on the rig (or the simulated one): ``(views, refused, (w, h), truth | None, camera table)``."""
    from gonio.errors import ConfigError
    from gonio.rig.kinematics import load_rig, read_rig_text
    from gonio.session.camera_views import capture_views, view_plan

    if args.sim:
        from gonio.plugins import plugin
        from gonio.session.options import load_material_file
        from gonio.session.rigs import open_sim_config

        text, src = read_rig_text(args.rig or "default")
        rig = load_rig(text=text, source=src)
        dx, dy = _floats(args.sim_principal_offset, "--sim-principal-offset", 2)
        dist = _floats(args.sim_distortion, "--sim-distortion", 5)
        config = plugin("sim.rig").SimRigConfig.at_resolution(*size, seed=args.seed, principal_offset_px=(dx, dy),
                                                              distortion=tuple(dist), camera_link=args.sim_camera)
        truth = config.true_calibration()
        opened = open_sim_config(rig, text, src, config, load_material_file(None), None, detector=False)
        camera_table = {"linear": True, "bit_depth": config.bit_depth}
    else:
        from gonio.rig.calibration import CameraSettings
        from gonio.rig.clock import RealClock
        from gonio.session.rigs import open_hardware_devices

        missing = [o for o, v in (("--rig", args.rig), ("--servo-port", args.servo_port),
                                  ("--controller-port", args.controller_port)) if not v]
        if missing:
            raise ConfigError(f"gonio camera calibrate --camera: views on the rig need {', '.join(missing)} (or give "
                              "--images of the board)")
        rig = load_rig(args.rig)
        aravis = args.backend.lower() == "aravis"
        settings = CameraSettings(linear=aravis, backend=args.backend.lower(), gain_unit=args.gain_unit,
                                  pixel_format=args.pixel_format if aravis else None,
                                  bit_depth=_bits(args.pixel_format) if aravis else 8)
        devices = open_hardware_devices(rig, {"servo_port": args.servo_port, "controller_port": args.controller_port,
                                              "camera": args.camera}, settings, RealClock())
        opened, truth, camera_table = _Closing(devices), None, {}
    with opened:
        plan = view_plan(rig)
        if args.quick:
            plan = plan[::3]
        views, refused = capture_views(opened.devices, spec, plan, on_view=_progress, covers=covers)
        frame = opened.devices.camera.capture(0.005, 1.0)
    size = (frame.pixels.shape[1], frame.pixels.shape[0])
    return views, refused, size, truth, camera_table


class _Closing:
    """Devices as a context manager (their ``close`` on leaving)."""

    def __init__(self, devices):
        self.devices = devices

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.devices.close()


def _bits(pixel_format: str) -> int:
    from gonio.rig.aravis import PIXEL_FORMATS

    return PIXEL_FORMATS.get(pixel_format, (8,))[0]


def _progress(k: int, n: int, view) -> None:
    if sys.stderr.isatty():
        print(f"\rview {k + 1}/{n}", end="" if k + 1 < n else "\n", file=sys.stderr, flush=True)


def _write_intrinsics(args, res, camera_table: dict, how: str) -> None:
    import time

    from gonio.pipeline.intrinsics import DIST_MODELS, PARAMS
    from gonio.rig.camera_toml import write_camera_toml

    estimated = DIST_MODELS[res.model][1]
    record = {"method": "Zhang 2000 via OpenCV calibrateCameraExtended, ChArUco corners", "views_from": how,
              "dist_model": res.model, "dist_model_note": res.note, "views": len(res.view_rms_px), "rms_px": res.rms_px,
              **{f"sigma_{p}": res.sigma[p] for p in PARAMS[:4]},
              "sigma_dist": [res.sigma[p] if p in estimated else 0.0 for p in PARAMS[4:]],
              "coverage_radius": res.coverage.radius, "tilted_views": int((res.coverage.tilts_deg >= 15).sum()),
              "not_identified": list(res.not_identified), "missing": list(res.coverage.missing),
              "date": time.strftime("%Y-%m-%d")}
    updates = {"width": res.width, "height": res.height, "K": res.K.tolist(), "dist": res.dist.tolist(),
               "intrinsics": record}
    if camera_table:
        updates["camera"] = camera_table
    replaced = write_camera_toml(args.output, updates, force=args.force, remove=("focal_px",),
                                 command="gonio camera calibrate")
    print(f"wrote {args.output} (width, height, K, dist, [intrinsics])"
          + (f"; replaced {', '.join(replaced)}" if replaced else ""))


# -- noise -----------------------------------------------------------------------------------------------------
def run_noise(args) -> int:
    import contextlib

    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output
    from gonio.pipeline.emva1288 import analyse, capture_series

    check_output(args.output, option="-o", force=args.force, suffixes=(".toml",))
    if not 5 <= args.steps <= 1000:
        raise ConfigError.field("--steps", "steps", args.steps, "must be in [5, 1000] (EMVA 1288: 50 or more)")
    if not 2 <= args.average <= 1000:
        raise ConfigError.field("--average", "average", args.average, "must be in [2, 1000] (EMVA 1288: 16 or more)")
    darks = _floats(args.dark_exposures, "--dark-exposures", positive=True)
    if not 1.0 <= args.gain <= 64.0:
        raise ConfigError.field("--gain", "gain", args.gain, "must be in [1, 64]")
    channel = "RGB".index(args.channel)
    with contextlib.ExitStack() as stack:
        camera, light, truth = _noise_camera(args, stack)
        exposures, (w, h) = _exposure_range(camera, light, args.steps, args.gain, channel)
        print(f"photon transfer: {args.steps} exposures {exposures[0] * 1e3:.3g} .. {exposures[-1] * 1e3:.3g} ms, "
              f"2 light + 2 dark frames each, {args.average} averaged for DSNU/PRNU", file=sys.stderr)
        data = capture_series(camera, light, exposures, gain=args.gain, average=args.average, dark_exposures=darks,
                              channel=channel)
    res = analyse(data)
    print("\n".join(res.lines()))
    if truth is not None:
        print(f"  vs the simulated sensor: K {res.gain / truth['gain'] - 1:+.2%}, read noise "
              f"{res.read_noise_e / truth['read_noise_e'] - 1:+.2%}")
    from gonio.rig.camera_toml import write_camera_toml

    updates = {"width": w, "height": h, "noise": res.noise_table(), "emva1288": res.emva_table(),
               "camera": {"linear": True, "bit_depth": res.bit_depth, "black_level": round(res.dark_offset_dn, 3)}}
    replaced = write_camera_toml(args.output, updates, force=args.force, command="gonio camera noise")
    print(f"wrote {args.output} ([noise], [emva1288], [camera] black_level)"
          + (f"; replaced {', '.join(replaced)}" if replaced else ""))
    import tomllib
    from pathlib import Path

    if not {"K", "focal_px"} & set(tomllib.loads(Path(args.output).read_text(encoding="utf-8"))):
        print(f"{args.output} is without intrinsics yet: add them with `gonio camera calibrate ... -o {args.output} "
              "--force`")
    return 0


def _noise_camera(args, stack):
    """``(camera, light(on), truth | None)`` for ``gonio camera noise``."""
    from gonio.errors import ConfigError

    if not args.sim:
        from gonio.rig.controller import RigController

        if not args.controller_port:
            raise ConfigError("gonio camera noise --camera: --controller-port is required (the rig's light is switched "
                              "off for the dark frames; the camera looks at a uniform, diffusely lit target)")
        camera = open_camera_from_args(args)
        stack.callback(camera.close)
        ctl = RigController.open(args.controller_port)
        stack.callback(ctl.close)
        return camera, lambda on: ctl.set_light(on, 1.0) if on else ctl.set_light(False), None
    from gonio.brdf import make
    from gonio.session.options import parse_resolution as _resolution
    from gonio.pipeline.target import CameraCalibration, TargetLayout
    from gonio.plugins import plugin

    simcam = plugin("sim.camera")
    w, h = _resolution(args.sim_resolution)
    if args.sim_bit_depth not in (8, 10, 12, 14, 16):
        raise ConfigError.field("--sim-bit-depth", "sim_bit_depth", args.sim_bit_depth, "must be 8, 10, 12, 14 or 16")
    sensor = simcam.SensorModel(bit_depth=args.sim_bit_depth, dsnu=0.2, prnu=0.01)
    calib = CameraCalibration.pinhole(w, h, 380.0 * w / 320)
    # a uniform irradiance that fills the full well in ~12 ms at gain 1
    scene = simcam.SimScene(layout=TargetLayout(), material=make("lambert", albedo=(0.5, 0.5, 0.5)),
                            flat_field=sensor.full_well / 0.012)
    camera = simcam.SimCamera(calib, sensor, scene, seed=args.seed, clock=plugin("sim.clock").SimClock())
    light = lambda on: camera.set_light(on=on)  # noqa: E731
    truth = {"gain": sensor.dn_per_electron * args.gain, "read_noise_e": sensor.read_noise_e}
    if args.sim_camera == "gige":
        from gonio.rig.aravis import AravisCamera

        server = stack.enter_context(plugin("sim.gige_camera").GigECameraServer(camera))
        gige = AravisCamera(server.device, camera.clock, pixel_format=args.pixel_format, gain_unit="raw",
                            width=w, height=h)
        stack.callback(gige.close)
        return gige, light, None
    return camera, light, truth


def _exposure_range(camera, light, steps: int, gain: float, channel: int):
    """``steps`` exposures from near dark to 1.25× the exposure that fills the range (found by a probe: from
    0.1 ms, ×4 until the signal exceeds 5 % of the range, then extrapolated linearly)."""
    import numpy as np

    from gonio.errors import HardwareError

    def level(t):
        f = camera.capture(t, gain)
        px = np.asarray(f.pixels)
        return float((px[..., channel] if px.ndim == 3 else px).mean()), f

    light(False)
    dark, f = level(1e-4)
    full = float((1 << f.bit_depth) - 1)
    light(True)
    t = 1e-4
    while True:
        m, _ = level(t)
        if m - dark > 0.05 * (full - dark) or t >= 0.5:
            break
        t *= 4.0
    if m - dark <= 0.01 * (full - dark):
        raise HardwareError(f"camera noise: the signal at {t:g} s is {m - dark:.3g} DN above dark: no light on the "
                            "sensor (the light off? the lens capped?)", device="camera")
    t_full = t * (full - dark) / (m - dark)
    return list(np.linspace(0.01 * t_full, 1.25 * t_full, steps)), (f.pixels.shape[1], f.pixels.shape[0])


# -- opening the camera the options name (gonio camera's actions and these) ---------------------------------
def open_camera_from_args(args):
    """The camera the options name (``--sim``: the simulated one; else the backend and device), opened."""
    from gonio.errors import ConfigError

    if args.sim:
        return _sim_camera(args)
    from gonio.rig.calibration import BACKENDS
    from gonio.rig.camera import OpenCVCamera
    from gonio.rig.clock import RealClock

    backend = args.backend.lower()
    if backend not in BACKENDS:
        raise ConfigError.field("--backend", "backend", args.backend, f"must be one of {', '.join(BACKENDS)}")
    if backend == "aravis":
        from gonio.rig.aravis import AravisCamera

        return AravisCamera(args.camera, RealClock(), pixel_format=args.pixel_format, gain_unit=args.gain_unit)
    if not args.exposure_unit > 0:
        raise ConfigError.field("--exposure-unit", "exposure_unit", args.exposure_unit, "must be positive")
    # raw frames: no linearization here (the response is what `response` measures)
    return OpenCVCamera(args.camera, RealClock(), backend=BACKENDS[backend], exposure_unit=args.exposure_unit)


def _sim_camera(args):
    from gonio.brdf import make
    from gonio.session.options import parse_resolution as _resolution
    from gonio.errors import ConfigError
    from gonio.pipeline.target import CameraCalibration, TargetLayout
    from gonio.plugins import plugin

    simcam, SimClock = plugin("sim.camera"), plugin("sim.clock").SimClock  # docs/architecture.md §1: found, not imported
    SensorModel, SimCamera, SimScene = simcam.SensorModel, simcam.SimCamera, simcam.SimScene

    w, h = _resolution(args.sim_resolution)
    if not (args.sim_gamma > 0):
        raise ConfigError.field("--sim-gamma", "gamma", args.sim_gamma, "must be positive")
    sensor = SensorModel(bit_depth=args.sim_bit_depth, linear=args.sim_bit_depth != 8, gamma=args.sim_gamma)
    focal = plugin("sim.rig").SimRigConfig.at_resolution(w, h).focal_px  # the simulated rig's camera
    calib = CameraCalibration.pinhole(w, h, focal, noise=sensor.noise_model())
    scene = SimScene(layout=TargetLayout(), material=make("lambert", albedo=(0.5, 0.5, 0.5)))
    return SimCamera(calib, sensor, scene, seed=args.seed, clock=SimClock())
