"""The simulated rig's camera behind a real GigE Vision link: Aravis's fake GigE Vision camera
(``ArvGvFakeCamera``, the device ``arv-fake-gv-camera-0.8`` runs) on the loopback interface, whose
frames are rendered by the rig's :class:`sim.camera.SimCamera` at the exposure and gain the host wrote
into the camera's registers.

The host opens it like any GigE camera, ``AravisCamera("gige://127.0.0.1", ...)``
(:mod:`gonio.rig.aravis`): discovery protocol (GVCP), GenICam XML, register writes, software trigger
and the GVSP stream are all real; only the sensor is simulated. The fill callback is given to Aravis
through ctypes (``arv_fake_camera_set_fill_pattern``): PyGObject frees a callback of that scope as soon
as the setter returns, ctypes keeps it for the server's lifetime.

Pixel formats this server offers and fills: the fake device's own ``RGB8``, ``Mono8``/``Mono16`` (mean
of R, G, B) and ``BayerRG8``/``GR8``/``GB8``/``BG8`` (the rendered frame mosaiced), and the 12-bit ``RGB12``,
``Mono12`` and ``Bayer*12`` it adds to the device's GenICam XML (:data:`ADDED_FORMATS`), so that the default
12-bit simulated camera crosses GigE Vision at its own depth. Each format's full scale is the rendered
frame's saturation level.

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

__all__ = ["GigECameraServer", "FILLABLE_FORMATS", "ADDED_FORMATS", "FORMAT_BITS", "TEMPERATURE_REGISTER",
           "served_formats", "served_xml"]

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

#: GigE Vision's heartbeat-timeout bootstrap register (GigE Vision 2.0 §28, ms), and the value this server gives it.
HEARTBEAT_TIMEOUT_REGISTER, HEARTBEAT_TIMEOUT_MS = 0x0938, 60_000

#: PFNC pixel format codes (GenICam PFNC 2.x) of the formats this server fills: the fake device's own
#: (Mono8, Mono16, RGB8, Bayer*8) and :data:`ADDED_FORMATS`.
FILLABLE_FORMATS = {0x01080001: "Mono8", 0x01100007: "Mono16", 0x02180014: "RGB8",
                    0x01080009: "BayerRG8", 0x01080008: "BayerGR8", 0x0108000A: "BayerGB8",
                    0x0108000B: "BayerBG8", 0x01100005: "Mono12", 0x0230001A: "RGB12",
                    0x01100011: "BayerRG12", 0x01100010: "BayerGR12", 0x01100012: "BayerGB12", 0x01100013: "BayerBG12"}
#: Formats the fake device's GenICam XML does not list and this server adds to its ``PixelFormat`` enumeration
#: (12-bit formats, unpacked in 16-bit little-endian containers; RGB12 is PFNC 0x0230001A, 48 bits a pixel), so
#: the simulated 12-bit camera can be read at its own depth, in colour.
ADDED_FORMATS = ("Mono12", "RGB12", "BayerRG12", "BayerGR12", "BayerGB12", "BayerBG12")
#: Significant bits of each filled format.
FORMAT_BITS = {name: (8 if name.endswith("8") else 12 if name.endswith("12") else 16) for name in FILLABLE_FORMATS.values()}
_PIXEL_FORMAT_ANCHOR = "\t\t<pValue>PixelFormatRegister</pValue>"
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


def served_xml(Aravis, serial: str = "GONIO-SIM") -> tuple[str, list[str]]:
    """The GenICam XML this server serves (the fake device's own, with :data:`ADDED_FORMATS` added to its
    ``PixelFormat`` enumeration when it has one) and the pixel formats it offers and fills."""
    xml = Aravis.FakeCamera.new(serial).get_genicam_xml()[0]
    start = xml.find('<Enumeration Name="PixelFormat"')
    anchor = xml.find(_PIXEL_FORMAT_ANCHOR, start) if start >= 0 else -1
    if anchor >= 0:
        code = {v: k for k, v in FILLABLE_FORMATS.items()}
        entries = "".join(f'\t\t<EnumEntry Name="{n}" NameSpace="Standard">\n\t\t\t<Value>{code[n]}</Value>\n'
                          "\t\t</EnumEntry>\n" for n in ADDED_FORMATS)
        xml = xml[:anchor] + entries + xml[anchor:]
    end = xml.find("</Enumeration>", start)
    listed = xml[start:end] if start >= 0 else ""
    offered = [n for n in FILLABLE_FORMATS.values() if f'<EnumEntry Name="{n}"' in listed]
    return xml, offered


def served_formats() -> list[str]:
    """The pixel formats a :class:`GigECameraServer` offers here (this Aravis's fake device's XML decides)."""
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis

    return served_xml(Aravis)[1]


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
        # GigE Vision bootstrap register 0x0938, the heartbeat timeout (ms; the device's default 3,000): a frame
        # rendered in the fill callback holds the device's registers, so its control channel does not answer
        # while a slow frame renders (the first one, compiling its kernels: seconds), and the device would
        # drop its controller after the timeout and never send again; a rig's camera renders nothing
        self._fake.write_register(HEARTBEAT_TIMEOUT_REGISTER, HEARTBEAT_TIMEOUT_MS)
        self._lib.arv_fake_camera_set_fill_pattern(_gpointer(self._fake), self._callback, None)

    @staticmethod
    def _start(Aravis, address: str, serial: str, temperature: bool):
        """The fake device, with the fake camera's own GenICam XML plus :data:`ADDED_FORMATS` (where its XML has
        the ``PixelFormat`` enumeration to add them to) and ``DeviceTemperature`` if asked."""
        xml, _ = served_xml(Aravis, serial)
        if temperature:
            if "<!-- Port -->" not in xml:
                raise OSError("this Aravis's fake camera XML has no <!-- Port --> marker to add DeviceTemperature at")
            xml = xml.replace("\t<!-- Port -->", _TEMPERATURE_XML + "\t<!-- Port -->", 1)
        fd, path = tempfile.mkstemp(prefix="gonio-gige-", suffix=".xml")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(xml)
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
            top = 2 ** FORMAT_BITS[name] - 1  # the format's full scale: the frame's saturation level maps onto it
            dtype = np.uint8 if top == 255 else np.dtype("<u2")
            scaled = px * (top / frame.saturation_level)
            if name.startswith("Mono"):
                out = np.rint(scaled.mean(axis=2)).astype(dtype)
            else:
                rgb = np.rint(scaled).astype(dtype)
                out = rgb if name.startswith("RGB") else mosaic(rgb, name[5:7])
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
