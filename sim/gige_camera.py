"""The simulated rig's camera behind a real GigE Vision link: Aravis's fake GigE Vision camera
(``ArvGvFakeCamera``, the device ``arv-fake-gv-camera-0.8`` runs) on the loopback interface, whose
frames are rendered by the rig's :class:`sim.camera.SimCamera` at the exposure and gain the host wrote
into the camera's registers.

The host opens it like any GigE camera, ``AravisCamera("gige://127.0.0.1", ...)``
(:mod:`gonio.rig.aravis`): discovery protocol (GVCP), GenICam XML, register writes, software trigger
and the GVSP stream are all real; only the sensor is simulated. The fill callback is given to Aravis
through ctypes (``arv_fake_camera_set_fill_pattern``): PyGObject frees a callback of that scope as soon
as the setter returns, ctypes keeps it for the server's lifetime.

Pixel formats the fake device offers and this server fills: ``RGB8`` (default; the rendered frame as
is, an 8-bit linear sensor), ``Mono8``/``Mono16`` (mean of R, G, B) and ``BayerRG8``/``GR8``/``GB8``/
``BG8`` (the rendered frame mosaiced).

A rendering camera that reports its sensor temperature (``frame.meta["sensor_temp_c"]``, as
:class:`sim.camera.SimCamera` does by default) is served with the SFNC feature ``DeviceTemperature``
(°C, read-only; GenICam SFNC 2.7 §2.1 "DeviceControl"): the fake device's GenICam XML gets a
``FloatReg`` at :data:`TEMPERATURE_REGISTER`, written before each frame leaves, so the host reads the
temperature of the frame it has just received — what a machine-vision camera with a sensor
thermometer offers.
"""

from __future__ import annotations

import ctypes
import os
import struct
import tempfile
import threading

import numpy as np

__all__ = ["GigECameraServer", "FILLABLE_FORMATS", "TEMPERATURE_REGISTER"]

#: Register of the served ``DeviceTemperature`` (IEEE float32, big-endian): unused by the fake
#: device's own XML (its registers are 0x48-0x30c; 0x1e0 lies between SensorWidth and TestRegister).
TEMPERATURE_REGISTER = 0x1E0
_TEMPERATURE_XML = f"""
\t<Category Name="DeviceTemperatureControl" NameSpace="Custom">
\t\t<pFeature>DeviceTemperature</pFeature>
\t</Category>
\t<FloatReg Name="DeviceTemperature" NameSpace="Standard">
\t\t<Description>Sensor temperature of the last frame (degrees Celsius)</Description>
\t\t<Address>0x{TEMPERATURE_REGISTER:x}</Address>
\t\t<Length>4</Length>
\t\t<AccessMode>RO</AccessMode>
\t\t<pPort>Device</pPort>
\t\t<Endianess>BigEndian</Endianess>
\t\t<Unit>C</Unit>
\t</FloatReg>
"""

#: PFNC pixel format codes (GenICam PFNC 2.x) of the formats this server fills.
FILLABLE_FORMATS = {0x01080001: "Mono8", 0x01100007: "Mono16", 0x02180014: "RGB8",
                    0x01080009: "BayerRG8", 0x01080008: "BayerGR8", 0x0108000A: "BayerGB8",
                    0x0108000B: "BayerBG8"}
#: Row/column offsets of R, G (first), B in a 2×2 Bayer block, by PFNC name (top-left colour first).
_BAYER_SITES = {"RG": ((0, 0), (0, 1), (1, 1)), "GR": ((0, 1), (0, 0), (1, 0)),
                "GB": ((1, 0), (0, 0), (0, 1)), "BG": ((1, 1), (0, 1), (0, 0))}

_FILL = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32)


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer mosaic (H, W) of an RGB image (H, W, 3) with PFNC pattern ``pattern`` (``RG``, ...),
    green taken at both green sites."""
    out = np.empty(rgb.shape[:2], dtype=rgb.dtype)
    (ry, rx), (gy, gx), (by, bx) = _BAYER_SITES[pattern]
    out[ry::2, rx::2] = rgb[ry::2, rx::2, 0]
    out[by::2, bx::2] = rgb[by::2, bx::2, 2]
    out[gy::2, gx::2] = rgb[gy::2, gx::2, 1]
    oy, ox = 1 - gy, 1 - gx  # the other green site
    out[oy::2, ox::2] = rgb[oy::2, ox::2, 1]
    return out


def _libaravis():
    lib = ctypes.CDLL("libaravis-0.8.so.0")
    lib.arv_buffer_get_data.restype = ctypes.c_void_p
    lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    for name in ("arv_buffer_get_image_width", "arv_buffer_get_image_height"):
        getattr(lib, name).restype = ctypes.c_int
        getattr(lib, name).argtypes = [ctypes.c_void_p]
    lib.arv_fake_camera_set_fill_pattern.restype = None
    lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL, ctypes.c_void_p]
    return lib


def _gpointer(obj) -> int:
    """The C pointer of a PyGObject object (its ``__gpointer__`` capsule)."""
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype, get.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    return get(obj.__gpointer__, None)


class GigECameraServer:
    """Serve ``camera`` (anything with ``capture(exposure, gain) -> Frame``, e.g. a SimRig's
    ``camera``) as a GigE Vision device on ``address`` (loopback by default).

    ``gain_scale`` turns the camera's raw gain register into the linear gain given to ``camera``
    (the fake device's ``GainRaw`` is an integer; 1 = unity by default). Use as a context manager;
    :attr:`device` is what :class:`gonio.rig.aravis.AravisCamera` opens. Rendering errors are kept
    in :attr:`errors` (the frame is then left black, which the host's frame checks catch).
    ``temperature``: serve ``DeviceTemperature`` (default: when the camera's sensor reports it).
    """

    def __init__(self, camera, *, address: str = "127.0.0.1", serial: str = "GONIO-SIM", gain_scale: float = 1.0,
                 temperature: bool | None = None):
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis

        self.camera = camera
        self.address = address
        self.serial = serial
        self.gain_scale = float(gain_scale)
        self.errors: list[str] = []
        self.frames = 0
        self._lock = threading.Lock()
        self._lib = _libaravis()
        self._callback = _FILL(self._fill)  # kept alive as long as the server
        if temperature is None:
            temperature = bool(getattr(getattr(camera, "sensor", None), "reports_temperature", False))
        self.temperature = temperature
        self._server = self._start(Aravis, address, serial, temperature)
        if self._server is None or not self._server.is_running():
            raise OSError(f"cannot start a GigE Vision fake camera on {address}")
        self._fake = self._server.get_fake_camera()
        self._lib.arv_fake_camera_set_fill_pattern(_gpointer(self._fake), self._callback, None)

    @staticmethod
    def _start(Aravis, address: str, serial: str, temperature: bool):
        """The fake device, with the fake camera's own GenICam XML plus ``DeviceTemperature`` if asked."""
        if not temperature:
            return Aravis.GvFakeCamera.new(address, serial)
        xml = Aravis.FakeCamera.new(serial).get_genicam_xml()[0]
        if "<!-- Port -->" not in xml:
            raise OSError("this Aravis's fake camera XML has no <!-- Port --> marker to add DeviceTemperature at")
        fd, path = tempfile.mkstemp(prefix="gonio-gige-", suffix=".xml")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(xml.replace("\t<!-- Port -->", _TEMPERATURE_XML + "\t<!-- Port -->", 1))
            return Aravis.GvFakeCamera.new_full(address, serial, path)  # the XML is read here
        finally:
            os.unlink(path)

    @property
    def device(self) -> str:
        return f"gige://{self.address}"

    def _fill(self, buf, _data, exposure_us, gain_raw, pixel_format) -> None:
        try:
            name = FILLABLE_FORMATS.get(int(pixel_format))
            w = self._lib.arv_buffer_get_image_width(buf)
            h = self._lib.arv_buffer_get_image_height(buf)
            if name is None:
                raise ValueError(f"pixel format 0x{pixel_format:08x} not simulated")
            exposure = max(exposure_us, 1) * 1e-6
            with self._lock:
                frame = self.camera.capture(exposure, max(gain_raw * self.gain_scale, 1e-6))
            temp = (frame.meta or {}).get("sensor_temp_c")
            if self.temperature and temp is not None:
                self._fake.write_register(TEMPERATURE_REGISTER, struct.unpack(">I", struct.pack(">f", temp))[0])
            px = np.asarray(frame.pixels)
            if px.ndim == 2:
                px = np.repeat(px[..., None], 3, axis=2)
            if px.shape[0] < h or px.shape[1] < w:
                raise ValueError(f"rendered {px.shape[1]}x{px.shape[0]}, the host asked {w}x{h}")
            px = px[:h, :w]
            scale = frame.saturation_level
            if name in ("Mono8", "Mono16"):
                top = 255 if name == "Mono8" else 65535
                out = np.rint(px.mean(axis=2) * (top / scale)).astype(np.uint8 if top == 255 else "<u2")
            else:
                rgb8 = np.rint(px * (255.0 / scale)).astype(np.uint8)
                out = rgb8 if name == "RGB8" else mosaic(rgb8, name[5:7])
            data = np.ascontiguousarray(out).tobytes()
            size = ctypes.c_size_t()
            ptr = self._lib.arv_buffer_get_data(buf, ctypes.byref(size))
            ctypes.memmove(ptr, data, len(data))
            self.frames += 1
        except Exception as exc:  # noqa: BLE001 - inside a C callback: record, never raise
            self.errors.append(f"{type(exc).__name__}: {exc}")

    def close(self) -> None:
        """Stop serving: the device's threads end when Aravis finalizes it (its last reference)."""
        import gc

        if self._server is not None:
            self._server = self._fake = None
            gc.collect()

    def __enter__(self) -> "GigECameraServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
