"""``gonio camera info|capture|response``: the lab-bench camera tools (like ``gonio servo``).

``info`` shows what the driver offers (resolution, backend, manual exposure); ``capture`` saves one
raw frame (8/16-bit PNG or ``.npy``); ``response`` captures an exposure bracket of a static scene and
recovers the inverse response of an 8-bit non-linear camera (Debevec & Malik, SIGGRAPH 1997, through
:func:`gonio.pipeline.hdr.calibrate_response`), saved as the ``.npz`` that ``[camera] response`` of a
``CAMERA.toml`` names (:mod:`gonio.rig.calibration`).

``--sim`` uses the rendering camera (:class:`sim.camera.SimCamera`, by default its 8-bit gamma
response) looking at the standard target: the same commands run in CI without a camera. Like
``gonio measure --sim``, the simulator is found through :mod:`gonio.plugins`, not imported.
"""

from __future__ import annotations

import sys

from gonio.session.options import DEFAULT_SIM_RESOLUTION


def register(sub) -> None:
    p = sub.add_parser("camera", help="inspect a camera, capture a raw frame, calibrate an 8-bit response, "
                                      "calibrate intrinsics, measure noise (EMVA 1288)",
                       description="Lab-bench tools for the camera (OpenCV VideoCapture; --sim: the rendering "
                                   "camera).")
    csub = p.add_subparsers(dest="camera_command", metavar="ACTION", required=True)

    def common(sp):
        where = sp.add_mutually_exclusive_group(required=True)
        where.add_argument("--camera", metavar="N|ID", help="camera index or device path (OpenCV); with --backend "
                                                             "aravis a GenICam device id (gonio camera list) or "
                                                             "gige://ADDRESS")
        where.add_argument("--sim", action="store_true", help="the simulated camera (8-bit gamma by default)")
        sp.add_argument("--backend", default="v4l2", help="OpenCV backend: any, v4l2, gstreamer, ffmpeg; or aravis: "
                                                          "GenICam (GigE Vision / USB3 Vision) through Aravis")
        sp.add_argument("--pixel-format", default="Mono16", help="aravis: Mono8..Mono16, RGB8, BayerRG8, ... "
                                                                 "(default Mono16)")
        sp.add_argument("--gain-unit", default="dB", choices=("dB", "raw"), help="aravis: how the camera counts gain")
        sp.add_argument("--exposure-unit", type=float, default=1e-4,
                        help="seconds per CAP_PROP_EXPOSURE unit (V4L2: 1e-4)")
        sp.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for a frame")
        sp.add_argument("--sim-bit-depth", type=int, default=8, help="simulated sensor bit depth (8: gamma-encoded)")
        sp.add_argument("--sim-gamma", type=float, default=2.2, help="simulated 8-bit response y = 255 x^(1/gamma)")
        sp.add_argument("--sim-resolution", default=DEFAULT_SIM_RESOLUTION, metavar="WxH")
        sp.add_argument("--seed", type=int, default=0, help="simulated noise seed")
        sp.set_defaults(func=run)

    ls = csub.add_parser("list", help="the GenICam cameras Aravis discovers (GigE Vision, USB3 Vision)")
    ls.set_defaults(func=run_list)
    i = csub.add_parser("info", help="resolution, backend, whether manual exposure is accepted")
    common(i)
    c = csub.add_parser("capture", help="save one raw frame (PNG: 8/16-bit; or .npy)")
    common(c)
    c.add_argument("--exposure", type=float, required=True, help="exposure, seconds")
    c.add_argument("--gain", type=float, default=1.0, help="analogue gain (default 1)")
    c.add_argument("-o", "--output", required=True, metavar="FRAME.png|.npy")
    c.add_argument("--force", action="store_true", help="overwrite an existing output file")
    r = csub.add_parser("response", help="capture a bracket of a static scene and recover the inverse response")
    common(r)
    r.add_argument("--exposures", required=True, metavar="S,S,...", help="bracket, seconds (at least 3, e.g. "
                   "0.001,0.002,...,0.128: the darkest frame mostly dark, the brightest mostly saturated)")
    r.add_argument("--gain", type=float, default=1.0, help="analogue gain (default 1)")
    r.add_argument("--samples", type=int, default=100, help="pixels sampled by the Debevec solver")
    r.add_argument("-o", "--output", required=True, metavar="RESPONSE.npz")
    r.add_argument("--force", action="store_true", help="overwrite an existing output file")
    from gonio.cli.camera_char import register_actions

    register_actions(csub, common)  # calibrate, noise: the first day in the lab


def _positive(text: str, option: str) -> float:
    import math

    from gonio.errors import ConfigError

    try:
        v = float(text)
    except ValueError:
        raise ConfigError.field(option, option.lstrip("-"), text, "must be a number of seconds") from None
    if not (v > 0 and math.isfinite(v)):
        raise ConfigError.field(option, option.lstrip("-"), text, "must be positive")
    return v


def _save_frame(path: str, frame) -> None:
    from pathlib import Path

    import numpy as np

    from gonio.errors import ConfigError, DataError

    suffix = Path(path).suffix.lower()
    px = frame.pixels
    if suffix == ".npy":
        with open(path, "wb") as fh:
            np.save(fh, px, allow_pickle=False)
        return
    if suffix != ".png":
        raise ConfigError.field("-o", "output", path, "must end in .png or .npy")
    import cv2

    img = px[..., ::-1] if px.ndim == 3 else px  # RGB -> BGR for OpenCV
    if not cv2.imwrite(path, np.ascontiguousarray(img)):
        raise DataError(f"{path}: cannot write the PNG")


def run(args) -> int:
    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output

    if getattr(args, "output", None):  # before the camera is opened
        check_output(args.output, option="-o", force=args.force,
                     suffixes=(".png", ".npy") if args.camera_command == "capture" else (".npz",))
    from gonio.cli.camera_char import open_camera_from_args

    cam = open_camera_from_args(args)
    try:
        if args.camera_command == "info":
            return _info(cam, args)
        if args.camera_command == "capture":
            exposure = _positive(str(args.exposure), "--exposure")
            frame = cam.capture(exposure, args.gain, timeout=args.timeout)
            _save_frame(args.output, frame)
            px = frame.pixels
            print(f"{args.output}: {px.shape[1]}x{px.shape[0]} {px.dtype} ({frame.bit_depth}-bit, "
                  f"{'linear' if frame.linear else 'non-linear'}), exposure {frame.exposure:g} s, gain "
                  f"{frame.gain:g}, min {int(px.min())} max {int(px.max())}, "
                  f"{(px >= frame.saturation_level).mean() * 100:.1f} % saturated")
            return 0
        exposures = [_positive(t, "--exposures") for t in args.exposures.split(",") if t.strip()]
        if len(exposures) < 3 or len(set(exposures)) != len(exposures):
            raise ConfigError.field("--exposures", "exposures", args.exposures, "needs at least 3 different exposures")
        if not 10 <= args.samples <= 10000:
            raise ConfigError.field("--samples", "samples", args.samples, "must be in [10, 10000]")
        return _response(cam, sorted(exposures), args)
    finally:
        cam.close()


def run_list(args) -> int:
    from gonio.rig.aravis import list_devices

    devices = list_devices()
    if not devices:
        print("no GenICam camera found (GigE Vision cameras must be on a reachable subnet; USB3 Vision cameras "
              "need the udev rules of aravis)")
        return 1
    for d in devices:
        print(f"{d['id']:<32} {d['protocol']:<11} {d['vendor']} {d['model']} serial {d['serial']} at {d['address']}")
    return 0


def _info(cam, args) -> int:
    if args.sim:
        s, c = cam.sensor, cam.calibration
        rows = {"device": "sim", "backend": "SimCamera (rendering)", "width": c.width, "height": c.height,
                "bit_depth": s.bit_depth, "linear": "yes" if s.linear else f"no (8-bit, gamma {s.gamma:g})",
                "manual_exposure": f"yes ({s.min_exposure:g} .. {s.max_exposure:g} s)", "gain": "yes (1 .. 64)"}
    else:
        rows = cam.info()
    for k, v in rows.items():
        print(f"{k:16s} {v}")
    return 0


def _response(cam, exposures, args) -> int:
    import numpy as np

    from gonio.errors import ConfigError
    from gonio.pipeline.hdr import calibrate_response
    from gonio.rig.calibration import ResponseCurve

    frames = [cam.capture(t, args.gain, timeout=args.timeout) for t in exposures]
    if any(f.pixels.dtype != np.uint8 for f in frames):
        raise ConfigError.field("--camera", "bit depth", frames[0].bit_depth,
                                "response calibration is for 8-bit non-linear cameras; a raw 10-16-bit camera "
                                "is linear: declare linear = true and its bit_depth in [camera]")
    got = [f.exposure for f in frames]
    counts = sum(np.bincount(f.pixels.ravel(), minlength=256) for f in frames)
    coverage = float(np.mean(counts[16:241] >= 10))
    if coverage < 0.8:  # Debevec & Malik need every level of the curve seen in some frame
        raise ConfigError.field("--exposures", "exposures", args.exposures,
                                f"the frames show only {coverage:.0%} of the 8-bit levels 16..240: widen the "
                                "bracket (darkest frame mostly dark, brightest mostly saturated) or light the scene")
    curve = ResponseCurve.from_debevec(calibrate_response([f.pixels for f in frames], got, samples=args.samples),
                                       got, source=args.output)
    curve.save(args.output)
    inv = curve.inverse
    print(f"{args.output}: inverse response from {len(frames)} frames ({got[0]:g} .. {got[-1]:g} s)")
    print("value  " + "  ".join(f"{v:>7d}" for v in (16, 32, 64, 128, 192, 255)))
    for c in range(inv.shape[1]):
        name = "RGB"[c] if inv.shape[1] == 3 else "Y"
        print(f"{name:5s}  " + "  ".join(f"{inv[v, c]:7.4f}" for v in (16, 32, 64, 128, 192, 255)))
    print(f"add to CAMERA.toml: [camera] linear = false, bit_depth = 8, response = \"{args.output}\"", file=sys.stderr)
    return 0
