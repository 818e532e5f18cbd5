"""GenICam machine-vision cameras (GigE Vision, USB3 Vision) through Aravis, implementing
:class:`gonio.rig.interfaces.Camera`.

Aravis (https://github.com/AravisProject/aravis) is the open-source GenICam stack on Linux; gonio uses
it through PyGObject (``gi.repository.Aravis``, Debian ``gir1.2-aravis-0.8``; ``pip install
'gonio[genicam]'`` builds PyGObject). It reaches every GigE Vision and USB3 Vision camera that follows
the standards (Basler, FLIR/Teledyne, Allied Vision, IDS, Baumer, Hikrobot, Daheng, ...).

Physical units (GenICam SFNC, "Standard Features Naming Convention" 2.x):

* exposure: ``ExposureTime`` in µs (:meth:`Aravis.Camera.set_exposure_time`); gonio asks in seconds
  and records the value the camera reads back;
* gain: gonio's gain is a linear factor (1 = unity); SFNC ``Gain`` is in dB, so the camera receives
  ``20 log10(gain)`` dB (``gain_unit = "dB"``, the default) or the raw number (``gain_unit = "raw"``
  for cameras whose gain register has no unit);
* pixel formats (PFNC names): ``Mono8``, ``Mono10``, ``Mono12``, ``Mono14``, ``Mono16`` (unpacked,
  little-endian 16-bit containers), ``RGB8``, ``RGB12``, ``RGB16``, and Bayer ``BayerRG8/GR8/GB8/BG8`` and
  their 12- and 16-bit forms, demosaiced with OpenCV (bilinear) into RGB. Packed formats are refused in one
  line; a format the camera does not offer is refused naming the ones it does. The format is recorded in
  the session manifest (the camera's identity) and sets the frames' bit depth.

Triggering: without a hardware trigger each capture is a software trigger (``TriggerSource =
Software``), so the frame is exposed after the exposure was set; with ``trigger`` (the rig
controller's ``trigger_camera``) the camera waits on ``trigger_line`` (default ``Line0``) and the
controller fires the exposure. A frame that does not arrive within the timeout is a
:class:`~gonio.errors.HardwareTimeout`. Every frame is validated (payload status and type, pixel format,
width and height against those configured, buffer length): an incomplete frame (lost packets) or one that
fails a check (a zero-size frame, a region changed mid-session) is exposed again up to ``retries`` times,
then a :class:`~gonio.errors.HardwareError` naming the camera and the field, which the session retries or
reports like any other hardware fault.

Sensor temperature: a camera with the SFNC feature ``DeviceTemperature`` (°C; with
``DeviceTemperatureSelector`` set to ``Sensor`` where the camera has several thermometers) is read
after every frame and recorded as ``frame.meta["sensor_temp_c"]``, which the dark-current model
follows (:mod:`gonio.pipeline.dark`). A reading that is not a number in
[:data:`SENSOR_TEMP_RANGE`] °C is left out of the frame (the model then uses its latest dark check) and
counted in :attr:`AravisCamera.bad_temperatures`; a camera without the feature simply has no reading.
"""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from gonio.errors import ConfigError, HardwareError, HardwareTimeout
from gonio.rig.interfaces import Clock, Frame

__all__ = ["AravisCamera", "PIXEL_FORMATS", "SENSOR_TEMP_RANGE", "aravis_available", "list_devices"]

#: Sensor temperatures (°C) accepted from a camera: beyond any operating range of an image sensor,
#: a reading outside is a fault of the thermometer or the link, not a temperature.
SENSOR_TEMP_RANGE = (-60.0, 150.0)

#: PFNC pixel format → (bit depth, numpy dtype, Bayer pattern or None, channels).
PIXEL_FORMATS = {
    "Mono8": (8, np.uint8, None, 1), "Mono10": (10, np.uint16, None, 1), "Mono12": (12, np.uint16, None, 1),
    "Mono14": (14, np.uint16, None, 1), "Mono16": (16, np.uint16, None, 1), "RGB8": (8, np.uint8, None, 3),
    "RGB12": (12, np.uint16, None, 3), "RGB16": (16, np.uint16, None, 3),
    **{f"Bayer{p}8": (8, np.uint8, p, 1) for p in ("RG", "GR", "GB", "BG")},
    **{f"Bayer{p}12": (12, np.uint16, p, 1) for p in ("RG", "GR", "GB", "BG")},
    **{f"Bayer{p}16": (16, np.uint16, p, 1) for p in ("RG", "GR", "GB", "BG")},
}
#: OpenCV's demosaicing code for each PFNC Bayer pattern. OpenCV names a pattern by the 2×2 block
#: starting at the second row and column, PFNC by the top-left one: PFNC BayerRG (R at (0, 0)) is
#: OpenCV's "BG" code (tested against a mosaic of a known image).
_CV_BAYER = {"RG": "COLOR_BayerBG2RGB", "GR": "COLOR_BayerGB2RGB", "GB": "COLOR_BayerGR2RGB",
             "BG": "COLOR_BayerRG2RGB"}


def _aravis():
    """The ``gi.repository.Aravis`` module, or a one-line HardwareError saying what to install."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise HardwareError("GenICam cameras need Aravis: apt-get install gir1.2-aravis-0.8 and "
                            f"pip install 'gonio[genicam]' (PyGObject) ({exc})") from None
    return Aravis


def aravis_available() -> bool:
    """True when Aravis and PyGObject can be imported."""
    try:
        _aravis()
        return True
    except HardwareError:
        return False


def list_devices() -> list[dict]:
    """Every GenICam device Aravis discovers: id, vendor, model, serial, protocol, address."""
    Aravis = _aravis()
    Aravis.update_device_list()
    return [{"id": Aravis.get_device_id(i), "vendor": Aravis.get_device_vendor(i),
             "model": Aravis.get_device_model(i), "serial": Aravis.get_device_serial_nbr(i),
             "protocol": Aravis.get_device_protocol(i), "address": Aravis.get_device_address(i)}
            for i in range(Aravis.get_n_devices())]


def _open_device(Aravis, device: str):
    """An ``Aravis.Camera`` for ``device``: a device id as :func:`list_devices` prints it, or
    ``gige://ADDRESS`` for a GigE Vision camera at a known IP address (no discovery; the stream is
    received on the interface that routes to it, which also works on the loopback interface)."""
    if device and not device.startswith("gige://"):
        # a GigE camera discovered on the loopback interface (a simulator) is opened by address: the
        # stream must be received on loopback, not on the interface discovery answered through
        Aravis.update_device_list()
        for i in range(Aravis.get_n_devices()):
            if Aravis.get_device_id(i) == device and Aravis.get_device_protocol(i) == "GigEVision" \
                    and str(Aravis.get_device_address(i)).startswith("127."):
                device = f"gige://{Aravis.get_device_address(i)}"
    try:
        if device.startswith("gige://"):
            from gi.repository import Gio

            addr = Gio.InetAddress.new_from_string(device[len("gige://"):])
            if addr is None:
                raise ConfigError.field(None, "camera.device", device, "not an IP address after gige://")
            local = Gio.InetAddress.new_from_string("127.0.0.1") if addr.get_is_loopback() else None
            dev = Aravis.GvDevice.new(local, addr) if local is not None else Aravis.GvDevice.new(None, addr)
            if addr.get_is_loopback():  # the kernel's packet socket does not see loopback traffic
                dev.set_stream_options(Aravis.GvStreamOption.PACKET_SOCKET_DISABLED)
            return Aravis.Camera.new_with_device(dev)
        return Aravis.Camera.new(device or None)
    except ConfigError:
        raise
    except Exception as exc:  # GLib.Error: no such device, no answer
        raise HardwareError(f"camera {device!r}: cannot open through Aravis ({_glib_message(exc)})",
                            device=device) from None


def _glib_message(exc: BaseException) -> str:
    return getattr(exc, "message", None) or str(exc) or type(exc).__name__


def demosaic(raw: np.ndarray, pattern: str) -> np.ndarray:
    """RGB image from a Bayer mosaic with PFNC pattern ``pattern`` (``RG``, ``GR``, ``GB``, ``BG``),
    by OpenCV's bilinear demosaicing (``cv2.cvtColor``); dtype kept."""
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(raw), getattr(cv2, _CV_BAYER[pattern]))


class AravisCamera:
    """A GenICam camera through Aravis.

    Parameters
    ----------
    device : str
        Aravis device id (``gonio camera list``), ``gige://ADDRESS``, or ``""`` for the first camera.
    clock : Clock
        Timestamps the frames.
    pixel_format : str
        One of :data:`PIXEL_FORMATS` (default ``Mono16``: the deepest unpacked monochrome format).
    black_level : float
        Pedestal in pixel units (from ``CAMERA.toml``; the pipeline subtracts it).
    gain_unit : {"dB", "raw"}
        How the camera's ``Gain`` register counts (SFNC: dB).
    trigger : callable, optional
        ``trigger(exposure)`` fires the hardware trigger (the rig controller); the camera then waits on
        ``trigger_line``.
    retries : int
        An incomplete frame (GigE Vision packets lost) is exposed again up to this many times before
        a :class:`~gonio.errors.HardwareError`.
    width, height : int, optional
        Region of interest from the sensor's origin (default: the whole sensor).
    """

    def __init__(self, device: str, clock: Clock, *, pixel_format: str = "Mono16", black_level: float = 0.0,
                 gain_unit: str = "dB", trigger: Callable[[float], None] | None = None,
                 trigger_line: str = "Line0", width: int | None = None, height: int | None = None,
                 n_buffers: int = 4, retries: int = 2):
        if pixel_format not in PIXEL_FORMATS:
            raise ConfigError.field(None, "camera.pixel_format", pixel_format,
                                    f"must be one of {', '.join(PIXEL_FORMATS)}")
        if gain_unit not in ("dB", "raw"):
            raise ConfigError.field(None, "camera.gain_unit", gain_unit, "must be dB or raw")
        self.device = str(device)
        self.clock = clock
        self.pixel_format = pixel_format
        self.bit_depth, self._dtype, self._bayer, self._channels = PIXEL_FORMATS[pixel_format]
        self.black_level = float(black_level)
        self.gain_unit = gain_unit
        self._trigger = trigger
        self.trigger_line = trigger_line
        #: Incomplete frames (lost packets) are taken again up to ``retries`` times; counted here.
        self.retries, self.incomplete = int(retries), 0
        #: ``DeviceTemperature`` readings refused (not a number in :data:`SENSOR_TEMP_RANGE`).
        self.bad_temperatures = 0
        self._has_temperature = False
        self._aravis = Aravis = _aravis()
        self._cam = _open_device(Aravis, self.device)
        self._stream = None
        self._exposure: float | None = None
        self._gain: float | None = None
        try:
            available = list(self._cam.dup_available_pixel_formats_as_strings())
            if pixel_format not in available:
                raise ConfigError.field(None, "camera.pixel_format", pixel_format,
                                        f"not offered by this camera (it offers {', '.join(available)})")
            self._cam.set_pixel_format_from_string(pixel_format)
            sw, sh = self._cam.get_sensor_size()
            w, h = int(width or sw), int(height or sh)
            if not (0 < w <= sw and 0 < h <= sh):
                raise ConfigError.field(None, "camera.width/height", f"{w}x{h}", f"must fit the sensor ({sw}x{sh})")
            self._cam.set_region(0, 0, w, h)
            #: The frame size every frame must have (the region as the camera reads it back).
            self.width, self.height = (int(v) for v in self._cam.get_region()[2:])
            self._format_code = int(self._cam.get_pixel_format())
            self._cam.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            if trigger is not None:
                self._cam.set_trigger(trigger_line)
            else:
                self._cam.set_trigger("Software")
            self._stream = self._cam.create_stream(None, None)
            self._tune_gige_stream(Aravis)
            payload = self._cam.get_payload()
            for _ in range(max(2, n_buffers)):
                self._stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._has_temperature = self._select_sensor_thermometer()
            self._cam.start_acquisition()
        except (ConfigError, HardwareError):
            self.close()
            raise
        except Exception as exc:  # GLib.Error from a register write the camera refused
            self.close()
            raise HardwareError(f"camera {self.device!r}: setup refused ({_glib_message(exc)})",
                                device=self.device) from None

    @property
    def trigger(self) -> Callable[[float], None] | None:
        """The hardware trigger (``trigger(exposure)``), or None for software triggers. Setting it
        switches the camera's trigger source (acquisition is stopped around the change, as GenICam
        cameras only accept ``TriggerSource`` while idle)."""
        return self._trigger

    @trigger.setter
    def trigger(self, fn: Callable[[float], None] | None) -> None:
        if (fn is None) == (self._trigger is None):
            self._trigger = fn
            return
        self._cam.stop_acquisition()
        try:
            self._cam.set_trigger(self.trigger_line if fn is not None else "Software")
        except Exception as exc:  # noqa: BLE001
            raise HardwareError(f"camera {self.device!r}: trigger source {self.trigger_line!r} refused "
                                f"({_glib_message(exc)})", device=self.device) from None
        finally:
            self._cam.start_acquisition()
        self._trigger = fn

    def _select_sensor_thermometer(self) -> bool:
        """Whether the camera has ``DeviceTemperature``; selects its ``Sensor`` thermometer if it has a
        selector offering one (SFNC ``DeviceTemperatureSelector``)."""
        dev = self._cam.get_device()
        if not dev.is_feature_available("DeviceTemperature"):
            return False
        if dev.is_feature_available("DeviceTemperatureSelector"):
            try:
                if "Sensor" in dev.dup_available_enumeration_feature_values_as_strings("DeviceTemperatureSelector"):
                    dev.set_string_feature_value("DeviceTemperatureSelector", "Sensor")
            except Exception:  # noqa: BLE001 - the camera's default thermometer is then read
                pass
        return True

    def sensor_temperature(self) -> float | None:
        """The camera's ``DeviceTemperature`` now (°C, rounded to 0.1), or None without a valid reading."""
        if not self._has_temperature or self._cam is None:
            return None
        try:
            t = float(self._cam.get_device().get_float_feature_value("DeviceTemperature"))
        except Exception:  # noqa: BLE001 - a failed read is a missing reading, not a failed frame
            t = math.nan
        lo, hi = SENSOR_TEMP_RANGE
        if not lo <= t <= hi:  # NaN fails too
            self.bad_temperatures += 1
            return None
        return round(t, 1)

    def _tune_gige_stream(self, Aravis) -> None:
        """A GigE Vision stream receives a frame as UDP packets: a socket buffer smaller than the frame
        loses packets whenever the process is busy (a fixed buffer of 4 payloads here; the kernel caps it
        at ``net.core.rmem_max``),
        and a frame is given up after ``frame-retention`` µs (Aravis default 100 ms; 500 ms here, as a
        loaded host may be slow to read). USB3 Vision streams have neither property."""
        names = {p.name for p in self._stream.list_properties()}
        if "socket-buffer" in names:
            self._stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.FIXED)
            self._stream.set_property("socket-buffer-size", int(min(4 * self._cam.get_payload(), 1 << 26)))
        if "frame-retention" in names:
            self._stream.set_property("frame-retention", 500_000)

    # -- identification ------------------------------------------------------------------------------
    def identity(self) -> dict:
        """What the camera says it is (recorded in the session manifest)."""
        cam = self._cam
        out = {"backend": "aravis", "device": self.device, "pixel_format": self.pixel_format,
               "gain_unit": self.gain_unit}
        for key, getter in (("vendor", "get_vendor_name"), ("model", "get_model_name"),
                            ("serial", "get_device_serial_number"), ("device_id", "get_device_id")):
            try:
                out[key] = getattr(cam, getter)()
            except Exception:  # noqa: BLE001 - optional fields of the identification
                pass
        try:
            out["version"] = cam.get_device().get_string_feature_value("DeviceVersion")
        except Exception:  # noqa: BLE001
            pass
        x, y, w, h = cam.get_region()
        out.update(width=int(w), height=int(h))
        return out

    def info(self, probe_exposure: float = 0.01) -> dict:
        """Identification, exposure and gain ranges in physical units, and a test of manual exposure."""
        d = self.identity()
        lo, hi = self._cam.get_exposure_time_bounds()
        d["exposure_range_s"] = f"{lo * 1e-6:g} .. {hi * 1e-6:g}"
        glo, ghi = self._cam.get_gain_bounds()
        d["gain_range"] = f"{glo:g} .. {ghi:g} {self.gain_unit}"
        d["pixel_formats"] = ", ".join(self._cam.dup_available_pixel_formats_as_strings())
        try:
            self._set_exposure(probe_exposure)
            d["manual_exposure"] = f"yes ({self._exposure:g} s read back for {probe_exposure:g} s)"
        except HardwareError as exc:
            d["manual_exposure"] = f"no: {exc}"
        return d

    # -- settings ------------------------------------------------------------------------------------
    def _set_exposure(self, exposure: float) -> None:
        lo, hi = self._cam.get_exposure_time_bounds()
        us = exposure * 1e6
        if not lo <= us <= hi:
            raise HardwareError(f"camera {self.device!r}: exposure {exposure:g} s outside the camera's range "
                                f"{lo * 1e-6:g} .. {hi * 1e-6:g} s", device=self.device)
        try:
            self._cam.set_exposure_time(us)
            got = self._cam.get_exposure_time()
        except Exception as exc:  # noqa: BLE001
            raise HardwareError(f"camera {self.device!r}: exposure {exposure:g} s refused ({_glib_message(exc)})",
                                device=self.device) from None
        if not math.isclose(got, us, rel_tol=0.05, abs_tol=2.0):
            raise HardwareError(f"camera {self.device!r}: exposure {exposure:g} s not accepted "
                                f"(reads back {got * 1e-6:g} s)", device=self.device)
        self._exposure = got * 1e-6

    def _set_gain(self, gain: float) -> None:
        if not (gain > 0 and math.isfinite(gain)):
            raise ConfigError.field(None, "camera.gain", gain, "must be a positive linear factor")
        value = 20.0 * math.log10(gain) if self.gain_unit == "dB" else gain
        lo, hi = self._cam.get_gain_bounds()
        if not lo - 1e-9 <= value <= hi + 1e-9:
            raise HardwareError(f"camera {self.device!r}: gain {gain:g} ({value:g} {self.gain_unit}) outside "
                                f"{lo:g} .. {hi:g} {self.gain_unit}", device=self.device)
        try:
            self._cam.set_gain(value)
        except Exception as exc:  # noqa: BLE001
            raise HardwareError(f"camera {self.device!r}: gain {gain:g} refused ({_glib_message(exc)})",
                                device=self.device) from None
        self._gain = gain

    # -- capture -------------------------------------------------------------------------------------
    def _drain(self) -> None:
        """Give back frames that arrived unasked (none in trigger mode, but a camera may send one)."""
        while True:
            buf = self._stream.try_pop_buffer()
            if buf is None:
                return
            self._stream.push_buffer(buf)

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        """Set exposure/gain (if changed), trigger (software, or the rig controller), and return the
        frame within ``timeout`` seconds (real time)."""
        if not (exposure > 0 and math.isfinite(exposure)):
            raise ConfigError.field(None, "camera.exposure", exposure, "must be a positive number of seconds")
        if not (timeout > 0 and math.isfinite(timeout)):
            raise ConfigError.field(None, "camera.timeout", timeout, "must be a positive number of seconds")
        if self._stream is None:
            raise HardwareError(f"camera {self.device!r}: capture after close", device=self.device)
        if self._exposure is None or not math.isclose(self._exposure, exposure, rel_tol=1e-3):
            self._set_exposure(exposure)
        if gain != self._gain:
            self._set_gain(gain)
        t0 = self.clock.now()
        deadline = time.monotonic() + timeout  # a real-time bound on the camera, not protocol time
        for _ in range(self.retries + 1):
            self._drain()
            pixels, status = self._one_frame(deadline, timeout)
            if pixels is not None:
                break
            self.incomplete += 1
        else:
            if status.startswith("frame "):  # a frame that arrived but is not the one configured
                raise HardwareError(f"camera {self.device!r}: {status}, {self.retries + 1} times", device=self.device)
            raise HardwareError(f"camera {self.device!r}: incomplete frame ({status}) {self.retries + 1} times "
                                "(lost packets: check the link, the NIC's MTU and receive buffers)", device=self.device)
        temp = self.sensor_temperature()
        return Frame(pixels=pixels, exposure=float(self._exposure), gain=float(gain), bit_depth=self.bit_depth,
                     black_level=self.black_level, timestamp=t0, linear=True,
                     meta={"device": self.device, "backend": "aravis", "pixel_format": self.pixel_format,
                           "trigger": "hardware" if self.trigger is not None else "software",
                           **({"sensor_temp_c": temp} if temp is not None else {})})

    def _one_frame(self, deadline: float, timeout: float):
        """Trigger one exposure and wait for its buffer: ``(pixels, "")``, or ``(None, status)`` for an
        incomplete frame (lost packets), which the caller retries."""
        if self._trigger is not None:
            self._trigger(float(self._exposure))
        else:
            try:
                self._cam.software_trigger()
            except Exception as exc:  # noqa: BLE001
                raise HardwareError(f"camera {self.device!r}: software trigger refused ({_glib_message(exc)})",
                                    device=self.device) from None
        left = deadline - time.monotonic()
        buf = self._stream.timeout_pop_buffer(max(1, int(left * 1e6))) if left > 0 else None
        if buf is None:
            raise HardwareTimeout(f"camera {self.device!r}: no frame within {timeout:g} s", device=self.device)
        try:
            if buf.get_status() != self._aravis.BufferStatus.SUCCESS:
                return None, buf.get_status().value_nick
            fault = self._frame_fault(buf)
            if fault:
                return None, fault
            return self._pixels(buf), ""
        finally:
            self._stream.push_buffer(buf)

    def _frame_fault(self, buf) -> str:
        """What is wrong with a frame the stream delivered as complete, naming the field (``frame width = 0:
        expected 640``), or ``""``: its payload type (an image), pixel format, width and height (those
        configured: a camera whose Width/Height changed mid-session, or a zero-size frame) and buffer length
        (what the format and size need). Every frame is checked: the frame is device input."""
        Aravis = self._aravis
        kind = buf.get_payload_type()
        if kind not in (Aravis.BufferPayloadType.IMAGE, Aravis.BufferPayloadType.CHUNK_DATA,
                        Aravis.BufferPayloadType.EXTENDED_CHUNK_DATA):
            return f"frame payload type = {kind.value_nick}: expected an image"
        fmt = int(buf.get_image_pixel_format())
        if fmt != self._format_code:
            return f"frame pixel format = 0x{fmt:08x}: expected {self.pixel_format} (0x{self._format_code:08x})"
        for field, got, want in (("width", buf.get_image_width(), self.width), ("height", buf.get_image_height(), self.height)):
            if got != want:
                return f"frame {field} = {got}: expected {want} (the camera's region changed, or a zero-size frame)"
        data = buf.get_data()
        need = self.width * self.height * self._channels * np.dtype(self._dtype).itemsize
        if data is None or len(data) < need:
            return (f"frame buffer length = {0 if data is None else len(data)} bytes: {self.pixel_format} "
                    f"{self.width}x{self.height} needs {need}")
        return ""

    def _pixels(self, buf) -> np.ndarray:
        """The frame as an (H, W) or (H, W, 3) array of the format's dtype (:meth:`_frame_fault` checked it)."""
        w, h = self.width, self.height
        data = buf.get_data()
        arr = np.frombuffer(data, dtype=np.dtype(self._dtype).newbyteorder("<"), count=w * h * self._channels)
        arr = arr.reshape((h, w, 3) if self._channels == 3 else (h, w)).astype(self._dtype, copy=True)
        if self._bayer is not None:
            arr = demosaic(arr, self._bayer)
        return arr

    def close(self) -> None:
        cam, self._stream = self._cam, None
        if cam is not None:
            try:
                cam.stop_acquisition()
            except Exception:  # noqa: BLE001 - closing: the camera may already be gone
                pass
        self._cam = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
