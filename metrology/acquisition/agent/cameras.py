"""Camera backends behind one small interface: OpenCV ``VideoCapture``, GenICam (``harvesters``), the virtual rig.

A backend is named on the command line by a spec:

- ``opencv:0`` (device index), ``opencv:/dev/video2`` or ``opencv:FILE.mp4`` (a video file, for
  testing: each grab reads the next frame);
- ``genicam:PRODUCER.cti[:INDEX]`` (GenICam/GigE Vision/USB3 Vision through the optional
  ``harvesters`` package);
- ``virtual`` (the virtual rig, :mod:`metrology.core.simulate`, through the rig's own model: it
  renders what the camera would see under the pattern the projector REPORTS it shows; on a stereo
  rig, what each of its two cameras would see).

Frames are single-channel ``(H, W)`` uint8 or uint16 arrays (colour cameras are converted to grey).

The sequencer drives a rig's cameras together (:class:`RigCameras`): each grab returns one frame
per camera of the rig, camera 0 first. A one-camera backend is :class:`SingleCamera`; two backends
of a stereo rig are a :class:`CameraPair` (exposed by one hardware trigger where both backends have
one, :class:`TriggeredCamera`, else grabbed one after the other once the pattern is shown and the
settle time is over); the virtual camera renders every camera of the rig itself. The rig decides:
the cameras must be as many as the rig file's (:func:`rig_camera_count`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from metrology.acquisition.agent.patterns import ProjectedCodec


@dataclass(frozen=True)
class Shown:
    """What the projector reported showing: ``kind`` (white, black, frame, ...) and ``frame``; ``seq`` its number."""

    kind: str
    frame: int = -1
    seq: int = 0


@dataclass(frozen=True)
class AcquisitionTarget:
    """What is in front of the rig for one acquisition (the virtual rig uses it to choose its scene)."""

    role: str
    z_in_mm: float | None = None
    repeat: int = 0
    codec: ProjectedCodec | None = None
    rig_geometry: dict[str, Any] = field(default_factory=dict)


class CameraError(Exception):
    """The camera cannot be opened or cannot grab (the message says why)."""


class Camera(Protocol):
    """The interface of a camera backend."""

    name: str

    def open(self) -> None:
        """Open the device (raises :class:`CameraError`)."""

    def prepare(self, target: AcquisitionTarget) -> None:
        """Called before each acquisition (real cameras ignore it)."""

    def set_exposure(self, exposure_ms: float) -> None:
        """Set the exposure time, ms (raises :class:`CameraError` if the device refuses)."""

    def grab(self, shown: Shown) -> np.ndarray:
        """One frame taken now, ``(H, W)`` uint8/uint16. ``shown`` is what the projector reports showing."""

    def expected(self, shown: Shown) -> np.ndarray | None:
        """The noise-free image expected under ``shown`` when the geometry is known, else None."""

    def close(self) -> None:
        """Release the device."""


@runtime_checkable
class RigCameras(Protocol):
    """The cameras of a rig, grabbed together under each projected pattern, camera 0 first."""

    name: str

    @property
    def camera_count(self) -> int:
        """How many frames each grab returns (the rig's cameras, once prepared)."""

    def open(self) -> None:
        """Open every device (raises :class:`CameraError`)."""

    def prepare(self, target: AcquisitionTarget) -> None:
        """Called before each acquisition; raises :class:`CameraError` when the rig has another number of cameras."""

    def set_exposure(self, exposure_ms: float) -> None:
        """Set every camera's exposure time, ms."""

    def grab(self, shown: Shown) -> tuple[np.ndarray, ...]:
        """One frame per camera under ``shown``, camera 0 first, each ``(H_c, W_c)`` uint8/uint16."""

    def expected(self, shown: Shown) -> tuple[np.ndarray | None, ...]:
        """Per camera, the noise-free image expected under ``shown`` when known, else None."""

    def close(self) -> None:
        """Release every device."""


@runtime_checkable
class TriggeredCamera(Protocol):
    """A backend whose frames can be exposed on a trigger (GenICam's ``TriggerMode``)."""

    name: str

    def use_trigger(self, source: str) -> None:
        """Expose one frame per trigger from ``source``: ``"Software"`` (:meth:`fire`) or an input line
        (``"Line0"``)."""

    def fire(self) -> None:
        """Issue a software trigger."""

    def discard(self) -> int:
        """Discard the frames delivered and not fetched yet (before a trigger); how many."""

    def fetch(self) -> np.ndarray:
        """The frame of the last trigger (waits for it), ``(H, W)`` uint8/uint16."""


def rig_camera_count(geometry: dict[str, Any]) -> int:
    """How many cameras the rig file ``geometry`` has (its model's ``cameras``); 1 without a rig file."""
    if not geometry:
        return 1
    from metrology.core.geometry import model_from_dict

    try:
        return int(model_from_dict(geometry).cameras)
    except ValueError as exc:
        raise CameraError(f"the rig's file cannot be read: {exc}") from None


def _check_camera_count(name: str, count: int, target: AcquisitionTarget) -> None:
    wanted = rig_camera_count(target.rig_geometry)
    if wanted != count:
        raise CameraError(
            f"the rig has {wanted} camera(s) and the agent drives {count} ({name}): give one camera per camera "
            "of the rig, camera 0 first (--camera SPEC --camera1 SPEC), or --camera virtual"
        )


class SingleCamera:
    """One backend as the cameras of a one-camera rig."""

    camera_count = 1

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self.name = camera.name

    def open(self) -> None:
        self.camera.open()

    def prepare(self, target: AcquisitionTarget) -> None:
        _check_camera_count(self.name, 1, target)
        self.camera.prepare(target)

    def set_exposure(self, exposure_ms: float) -> None:
        self.camera.set_exposure(exposure_ms)

    def grab(self, shown: Shown) -> tuple[np.ndarray, ...]:
        return (self.camera.grab(shown),)

    def expected(self, shown: Shown) -> tuple[np.ndarray | None, ...]:
        return (self.camera.expected(shown),)

    def close(self) -> None:
        self.camera.close()


class CameraPair:
    """Two backends as a stereo rig's cameras, camera 0 first.

    Without ``trigger_line`` a grab takes camera 0's frame, then camera 1's, both after the
    projector confirmed the pattern and the settle time passed (the pattern stays on while both are
    grabbed). With ``trigger_line`` both backends must have a hardware trigger
    (:class:`TriggeredCamera`): camera 0 exposes on a software trigger, camera 1 on its input line
    ``trigger_line``, wired to camera 0's exposure output (set up in the vendor's tool), so one
    :meth:`~TriggeredCamera.fire` exposes both at once; a grab discards both cameras' undelivered
    frames, fires and fetches both frames (a camera 1 that receives no trigger fails the grab after
    its timeout, naming it).
    """

    camera_count = 2

    def __init__(self, first: Camera, second: Camera, trigger_line: str | None = None) -> None:
        self.cameras = (first, second)
        self.trigger_line = trigger_line
        triggered = f" (triggered, camera 1 on {trigger_line})" if trigger_line else ""
        self.name = f"{first.name},{second.name}{triggered}"

    def open(self) -> None:
        """Open both (and set their triggers); on a refusal the cameras opened are closed again."""
        try:
            for camera in self.cameras:
                camera.open()
            if self.trigger_line is None:
                return
            first, second = self.cameras
            for camera in self.cameras:
                if not isinstance(camera, TriggeredCamera):
                    raise CameraError(f"camera {camera.name} has no hardware trigger (GenICam cameras have one)")
            assert isinstance(first, TriggeredCamera) and isinstance(second, TriggeredCamera)
            second.use_trigger(self.trigger_line)  # armed before camera 0 can expose
            first.use_trigger("Software")
        except CameraError:
            self.close()
            raise

    def prepare(self, target: AcquisitionTarget) -> None:
        _check_camera_count(self.name, 2, target)
        for camera in self.cameras:
            camera.prepare(target)

    def set_exposure(self, exposure_ms: float) -> None:
        for camera in self.cameras:
            camera.set_exposure(exposure_ms)

    def grab(self, shown: Shown) -> tuple[np.ndarray, ...]:
        first, second = self.cameras
        if self.trigger_line is None:
            return first.grab(shown), second.grab(shown)
        assert isinstance(first, TriggeredCamera) and isinstance(second, TriggeredCamera)
        second.discard()
        first.discard()
        first.fire()
        return first.fetch(), second.fetch()

    def expected(self, shown: Shown) -> tuple[np.ndarray | None, ...]:
        return tuple(camera.expected(shown) for camera in self.cameras)

    def close(self) -> None:
        for camera in self.cameras:
            camera.close()


def as_rig_cameras(camera: Camera | RigCameras) -> RigCameras:
    """``camera`` itself when it drives a rig's cameras, else a :class:`SingleCamera` of it."""
    return camera if isinstance(camera, RigCameras) else SingleCamera(camera)


def _grey(frame: np.ndarray) -> np.ndarray:
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if frame.ndim == 3:
        import cv2

        code = cv2.COLOR_BGRA2GRAY if frame.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        frame = cv2.cvtColor(frame, code)
    if frame.dtype not in (np.uint8, np.uint16):
        raise CameraError(f"the camera returned {frame.dtype} frames; uint8 or uint16 are needed")
    return np.ascontiguousarray(frame)


class OpenCVCamera:
    """A UVC webcam (device index or path) or a video file, through ``cv2.VideoCapture``.

    A live camera queues frames; each grab first discards ``flush`` frames so the frame
    returned was exposed after the call (after the projector's settle time). A video file is
    read one frame per grab (no flush).
    """

    def __init__(self, device: str, flush: int = 2) -> None:
        self.device = device
        self.is_file = not device.isdigit() and not device.startswith("/dev/")
        self.flush = 0 if self.is_file else flush
        self.name = f"opencv:{device}"
        self._capture: Any = None

    def open(self) -> None:
        import cv2

        source: int | str = int(self.device) if self.device.isdigit() else self.device
        capture = cv2.VideoCapture(source)
        if not capture.isOpened():
            raise CameraError(f"camera {self.name}: OpenCV cannot open {self.device!r}")
        self._capture = capture

    def prepare(self, target: AcquisitionTarget) -> None:
        return None

    def set_exposure(self, exposure_ms: float) -> None:
        import cv2

        if self._capture is None or self.is_file:
            return
        self._capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: manual
        if not self._capture.set(cv2.CAP_PROP_EXPOSURE, float(exposure_ms) * 10.0):  # V4L2 units of 100 us
            raise CameraError(f"camera {self.name} refused exposure {exposure_ms} ms")

    def grab(self, shown: Shown) -> np.ndarray:
        if self._capture is None:
            raise CameraError(f"camera {self.name} is not open")
        for _ in range(self.flush):
            self._capture.grab()
        ok, frame = self._capture.read()
        if not ok or frame is None:
            raise CameraError(f"camera {self.name}: no frame (end of the video or device lost)")
        return _grey(frame)

    def expected(self, shown: Shown) -> np.ndarray | None:
        return None

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


#: GenICam pixel formats (PFNC names) read as grey: the monochrome formats with their bit depth
#: (harvesters unpacks 10/12/14-bit and packed formats into uint16) and the colour formats with
#: their channel order for OpenCV's grey conversion.
GENICAM_MONO_BITS = {
    "Mono8": 8,
    "Mono10": 10,
    "Mono10p": 10,
    "Mono10Packed": 10,
    "Mono12": 12,
    "Mono12p": 12,
    "Mono12Packed": 12,
    "Mono14": 14,
    "Mono14p": 14,
    "Mono16": 16,
}
GENICAM_COLOUR = {
    "RGB8": "COLOR_RGB2GRAY",
    "BGR8": "COLOR_BGR2GRAY",
    "RGBa8": "COLOR_RGBA2GRAY",
    "BGRa8": "COLOR_BGRA2GRAY",
}


def genicam_grey(data: np.ndarray, width: int, height: int, pixel_format: str) -> np.ndarray:
    """One GenICam buffer's pixels as a grey ``(height, width)`` frame of the agent's depths.

    ``data`` is the buffer's component as harvesters gives it: 1-D, ``height * width * channels``
    values (uint8, or uint16 for the 10- to 16-bit monochrome formats). Monochrome formats of ``b``
    bits (8 < b < 16) are scaled to the full 16-bit range, ``I16 = round(I * 65535 / (2^b - 1))``
    (linear, 0 stays 0 and the sensor's full scale becomes 65535, so the agent's saturation and
    exposure checks see the sensor's own full scale); 8- and 16-bit formats are returned as they
    are. Colour formats become grey with OpenCV's weights in their channel order
    (``0.299 R + 0.587 G + 0.114 B``). Other formats (Bayer, YUV, signed, 3-D) raise
    :class:`CameraError` naming the format and the formats read.
    """
    if pixel_format in GENICAM_MONO_BITS:
        bits = GENICAM_MONO_BITS[pixel_format]
        frame = np.asarray(data).reshape(height, width)
        if bits == 8:
            return np.ascontiguousarray(frame, dtype=np.uint8)
        frame = frame.astype(np.uint16, copy=False)
        if bits == 16:
            return np.ascontiguousarray(frame)
        top = (1 << bits) - 1
        scaled = (np.minimum(frame, top).astype(np.uint32) * 65535 + top // 2) // top
        return scaled.astype(np.uint16)
    if pixel_format in GENICAM_COLOUR:
        import cv2

        channels = 4 if pixel_format.endswith("a8") else 3
        frame = np.ascontiguousarray(np.asarray(data, dtype=np.uint8).reshape(height, width, channels))
        return cv2.cvtColor(frame, getattr(cv2, GENICAM_COLOUR[pixel_format]))
    readable = ", ".join([*GENICAM_MONO_BITS, *GENICAM_COLOUR])
    raise CameraError(
        f"the camera sends {pixel_format} frames; set its PixelFormat to one of {readable} (Mono16 or Mono12 "
        "for the finest phase) in the vendor's tool"
    )


class _Producers:
    """One ``harvesters.Harvester`` per GenTL producer file in the process, shared by its cameras.

    A producer library is loaded once per process: a second ``Harvester`` of the same .cti finds
    no device (the first holds the transport layer), so the two cameras of a stereo rig on one
    vendor's producer share one. Counted: the last camera to close resets it.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[str, tuple[Any, int]] = {}

    def acquire(self, producer: str, harvester_class: Any) -> Any:
        key = str(Path(producer).resolve())
        with self._lock:
            if key in self._open:
                harvester, users = self._open[key]
            else:
                harvester, users = harvester_class(), 0
                try:
                    harvester.add_file(key)
                    harvester.update()
                except Exception:
                    harvester.reset()
                    raise
            self._open[key] = (harvester, users + 1)
            return harvester

    def release(self, producer: str) -> None:
        key = str(Path(producer).resolve())
        with self._lock:
            harvester, users = self._open.pop(key)
            if users > 1:
                self._open[key] = (harvester, users - 1)
            else:
                harvester.reset()


_PRODUCERS = _Producers()


class GenICamCamera:
    """A GenICam camera (GigE Vision, USB3 Vision) through ``harvesters`` and a vendor GenTL producer (.cti).

    The acquisition starts at the first grab (or :meth:`use_trigger`), not at :meth:`open`, so the
    trigger nodes can still be written. Free running, a grab discards the frames the camera
    delivered before the call and the ``flush`` frames after it (those exposing at the call), and
    returns the next one, exposed after the call; with a software trigger (:meth:`use_trigger`
    ``"Software"``) a grab discards what was delivered, fires and returns the frame of that trigger.
    ``timeout_s`` bounds every wait for a frame. Frames go through :func:`genicam_grey`.
    """

    def __init__(self, producer: str, index: int = 0, *, timeout_s: float = 10.0, flush: int = 1) -> None:
        self.producer = producer
        self.index = index
        self.timeout_s = timeout_s
        self.flush = flush
        self.name = f"genicam:{producer}:{index}"
        self.trigger: str | None = None
        self._harvester: Any = None
        self._acquirer: Any = None

    def open(self) -> None:
        try:
            from harvesters.core import Harvester  # optional extra
        except ImportError:
            raise CameraError(
                "GenICam cameras need the optional 'harvesters' package: pip install 'gcps-lab[genicam]' "
                "(and the camera vendor's GenTL producer, a .cti file)"
            ) from None
        if not Path(self.producer).is_file():
            raise CameraError(f"camera {self.name}: no GenTL producer at {self.producer} (the vendor's .cti file)")
        if self._harvester is not None:
            return
        try:
            harvester = _PRODUCERS.acquire(self.producer, Harvester)
        except Exception as exc:
            raise CameraError(f"camera {self.name}: the GenTL producer cannot be loaded: {exc}") from None
        try:
            found = len(harvester.device_info_list)
            if found <= self.index:
                raise CameraError(f"camera {self.name}: {found} GenICam device(s) found")
            self._acquirer = harvester.create(self.index)
        except Exception as exc:
            _PRODUCERS.release(self.producer)
            if isinstance(exc, CameraError):
                raise
            raise CameraError(f"camera {self.name} cannot be opened: {type(exc).__name__}: {exc}") from None
        self._harvester = harvester

    def prepare(self, target: AcquisitionTarget) -> None:
        return None

    def _nodes(self) -> Any:
        if self._acquirer is None:
            raise CameraError(f"camera {self.name} is not open")
        return self._acquirer.remote_device.node_map

    def _node(self, name: str) -> Any:
        """The feature ``name`` of the camera's node map, None when the camera has none."""
        try:
            return getattr(self._nodes(), name)
        except AttributeError:
            return None

    def _start(self) -> None:
        if not self._acquirer.is_acquiring():
            self._acquirer.start()

    def set_exposure(self, exposure_ms: float) -> None:
        """``ExposureTime`` (SFNC; ``ExposureTimeAbs`` on older cameras) in µs, ``ExposureAuto = Off`` first."""
        node = self._node("ExposureTime") or self._node("ExposureTimeAbs")
        if node is None:
            raise CameraError(
                f"camera {self.name} has no ExposureTime feature: it cannot take exposure {exposure_ms:g} ms"
            )
        try:
            auto = self._node("ExposureAuto")
            if auto is not None and auto.value != "Off":
                auto.value = "Off"
            node.value = float(exposure_ms) * 1000.0
        except Exception as exc:
            raise CameraError(f"camera {self.name} refused exposure {exposure_ms} ms: {exc}") from None

    def use_trigger(self, source: str) -> None:
        """``TriggerSelector = FrameStart`` (where the camera has the selector), ``TriggerMode = On``,
        ``TriggerSource = source``; the acquisition is stopped around the change (GenICam locks the
        trigger nodes while it runs) and started again, waiting for triggers. A source the camera's
        ``TriggerSource`` lacks is refused before anything changes."""
        nodes = self._nodes()
        missing = [name for name in ("TriggerMode", "TriggerSource") if self._node(name) is None]
        if missing:
            raise CameraError(f"camera {self.name} has no trigger ({', '.join(missing)} missing)")
        sources = [entry.symbolic for entry in nodes.TriggerSource.entries]
        if source not in sources:
            raise CameraError(
                f"camera {self.name} refused trigger source {source}: its TriggerSource offers {', '.join(sources)}"
            )
        if self._acquirer.is_acquiring():
            self._acquirer.stop()
        try:
            if self._node("TriggerSelector") is not None:
                nodes.TriggerSelector.value = "FrameStart"
            nodes.TriggerMode.value = "On"
            nodes.TriggerSource.value = source
        except Exception as exc:
            raise CameraError(f"camera {self.name} refused trigger source {source}: {exc}") from None
        self.trigger = source
        self._start()

    def fire(self) -> None:
        node = self._node("TriggerSoftware")
        if node is None:
            raise CameraError(f"camera {self.name} has no TriggerSoftware command")
        self._start()
        try:
            node.execute()
        except Exception as exc:
            raise CameraError(f"camera {self.name} refused a software trigger: {exc}") from None

    def discard(self) -> int:
        """Discard the frames already delivered (an acquisition not started has none); how many."""
        if self._acquirer is None or not self._acquirer.is_acquiring():
            return 0
        count = 0
        while (buffer := self._acquirer.try_fetch(timeout=0.001)) is not None:
            buffer.queue()
            count += 1
        return count

    def grab(self, shown: Shown) -> np.ndarray:
        self.discard()
        if self.trigger == "Software":
            self.fire()
        elif self.trigger is None:
            self._start()
            for _ in range(self.flush):
                self.fetch()
        return self.fetch()

    def fetch(self) -> np.ndarray:
        """The next frame delivered, waiting up to ``timeout_s`` (:class:`CameraError` then)."""
        if self._acquirer is None:
            raise CameraError(f"camera {self.name} is not open")
        self._start()
        try:
            buffer = self._acquirer.fetch(timeout=self.timeout_s)
        except Exception as exc:
            waiting = f" (waiting for a trigger on {self.trigger})" if self.trigger else ""
            raise CameraError(
                f"camera {self.name}: no frame within {self.timeout_s:g} s{waiting}: {type(exc).__name__}"
            ) from None
        with buffer:  # the buffer goes back to the camera on exit: read it (and copy) inside
            component = buffer.payload.components[0]
            return genicam_grey(
                np.array(component.data, copy=True), component.width, component.height, component.data_format
            )

    def expected(self, shown: Shown) -> np.ndarray | None:
        return None

    def close(self) -> None:
        if self._acquirer is not None:
            self._acquirer.destroy()  # stops a running acquisition first
        if self._harvester is not None:
            _PRODUCERS.release(self.producer)
        self._acquirer = self._harvester = None
        self.trigger = None


class VirtualCamera:
    """The virtual rig as the rig's cameras: the frames they would see under the pattern the projector reports.

    It renders through the rig's own geometric model (any model of the core's registry: the rig
    file the server sends, ``AcquisitionTarget.rig_geometry``) with the virtual rig's one entry,
    :func:`metrology.core.simulate.render_capture`. Scenes: a reference capture sees the reference
    plane, a stage capture the stage plane at ``z_in_mm``, an object or master capture
    ``object_scene`` (``{"name": ..., ...}``, :func:`metrology.core.scenes.make_scene`). The codec's
    frames are those of a direct simulation of the codec with ``options`` (same noise seed: the same
    images as ``gcps simulate`` at the nominal exposure); white and black frames come from
    :func:`metrology.core.simulate.render_flats` plus the same camera noise. Exposure scales all
    light linearly: ``ambient`` and ``projector_gain`` times ``exposure / nominal_exposure_ms``,
    then the frames are rounded and clipped to the bit depth (an 8-bit camera saturates at 255).

    ``object_scene`` may hold ``"hdr"``: ``true`` or an object of
    :class:`~metrology.core.simulate.exposures.HdrReflectance` fields, which replaces every
    scene's reflectance with a high-dynamic-range map (by default a specular patch of 1 on a dark
    matte part from 0.001 to 0.03, 1000:1, spanning the lit field) rendered through
    :func:`~metrology.core.simulate.exposures.render_exposures` (docs/exposures.md). Each exposure
    time then has its own camera noise (the seed follows the exposure). ``"distance_mm"`` places
    the scene facing the camera at that distance (default the model's own placement,
    :func:`~metrology.core.simulate.render.default_placement`).

    Two-camera mode: on a rig of two cameras (a stereo rig) each grab returns both cameras'
    frames, camera 0 first: the codec's frames are :func:`~metrology.core.simulate.render_capture`'s
    (:func:`~metrology.core.simulate.stereo.render_stereo_capture`: the same frames as ``gcps
    simulate`` of the stereo rig), the white and black frames
    :func:`~metrology.core.simulate.render_camera_flats`'s under the same projector, each camera with
    its own noise. HDR scenes on a stereo rig: one reflectance map over the scene for both cameras
    (camera 0's field, :func:`~metrology.core.simulate.exposures.scene_reflectance`), the frames
    :func:`~metrology.core.simulate.exposures.render_stereo_exposures`'s, the flats
    :func:`~metrology.core.simulate.render_camera_flats`'s under that map. A stereo rig's scene is
    cast once per acquisition (:func:`~metrology.core.simulate.stereo.cast_stereo`) and only lit
    anew at each exposure: the same frames as casting it for each (so is a one-camera rig's HDR scene).
    """

    def __init__(
        self,
        object_scene: dict[str, Any] | None = None,
        options: dict[str, Any] | None = None,
        nominal_exposure_ms: float = 10.0,
    ) -> None:
        from metrology.core.simulate import SimulationOptions

        self.object_scene = dict(object_scene or {"name": "sphere"})
        hdr = self.object_scene.pop("hdr", None)
        if hdr is not None and not isinstance(hdr, (bool, dict)):
            raise ValueError(f'scene "hdr" must be true or an object of reflectance fields, got {hdr!r}')
        self.hdr: dict[str, float] | None = None if not hdr else ({} if hdr is True else dict(hdr))
        distance = self.object_scene.pop("distance_mm", None)
        self.placement: Any = None
        if distance is not None:
            from metrology.core.simulate import ScenePlacement

            self.placement = ScenePlacement.facing_camera(float(distance))
        self.base_options = SimulationOptions(**(options or {}))
        self.nominal_exposure_ms = nominal_exposure_ms
        self.exposure_ms = nominal_exposure_ms
        self.name = "virtual"
        self.target: AcquisitionTarget | None = None
        self._cache: dict[str, Any] = {}
        self._reflectance: Any = None
        self._stereo_cast: Any = None
        self._camera_cast: Any = None

    @property
    def camera_count(self) -> int:
        """The prepared rig's cameras (1 before :meth:`prepare`)."""
        return 1 if self.target is None else int(self._rig().cameras)

    def open(self) -> None:
        return None

    def prepare(self, target: AcquisitionTarget) -> None:
        if not target.rig_geometry:
            raise CameraError("the virtual camera needs the rig's geometry")
        self.target = target
        try:
            self._rig()  # a rig of one or two cameras, HDR scenes or not
        except ValueError as exc:
            self.target = None
            raise CameraError(f"the virtual camera cannot render this rig: {exc}") from None
        self._cache = {}
        self._reflectance = None
        self._stereo_cast = None
        self._camera_cast = None

    def set_exposure(self, exposure_ms: float) -> None:
        if not exposure_ms > 0:
            raise CameraError(f"exposure must be positive, got {exposure_ms}")
        if exposure_ms != self.exposure_ms:
            self.exposure_ms = float(exposure_ms)
            self._cache = {}

    def _scene(self):
        from metrology.core.scenes import make_scene

        assert self.target is not None
        rig = self._rig()
        if self.target.role == "reference":
            return make_scene("reference")
        if self.target.role == "stage":
            return make_scene("stage", rig=rig, z_in_mm=float(self.target.z_in_mm or 0.0))
        spec = dict(self.object_scene)
        name = spec.pop("name")
        return make_scene(name, rig=rig, **spec)

    def _rig(self):
        """The rig's geometric model (``ValueError`` naming what is wrong with its file)."""
        from metrology.core.geometry import model_from_dict

        assert self.target is not None
        return model_from_dict(self.target.rig_geometry)

    def _codec(self):
        """The core's codec of the projected one (None: the paper's gcps-v1 at 1024x768)."""
        import json

        from metrology.core.codecs import builtin_codec, codec_from_dict

        assert self.target is not None
        projected = self.target.codec
        if projected is None:
            return None
        if projected.is_gcps_v1:
            return builtin_codec(projected.spec) if projected.spec.startswith("gcps-v1") else None
        return codec_from_dict(json.loads(projected.spec))

    def _options(self):
        scale = self.exposure_ms / self.nominal_exposure_ms
        opts = self.base_options
        if scale == 1.0:
            return opts
        return opts.with_changes(ambient=opts.ambient * scale, projector_gain=opts.projector_gain * scale)

    def _hdr_options(self):
        """This exposure's options; with an HDR map, its own noise seed (one per exposure time)."""
        opts = self._options()
        if self.hdr is None:
            return opts
        return opts.with_changes(seed=(opts.seed * 1_000_003 + round(self.exposure_ms * 1000)) % 2**31)

    def _projector_size(self, codec) -> tuple[int, int]:
        from metrology.core.codecs.model import gcps_v1_codec

        size = codec or gcps_v1_codec()
        return size.projector_width, size.projector_height

    def _hdr_reflectance(self, rig, scene, codec):
        from metrology.core.simulate.exposures import scene_reflectance

        if self._reflectance is None:
            changes = self.hdr or {}
            size = self._projector_size(codec)
            self._reflectance = scene_reflectance(rig, scene, size, placement=self.placement, **changes)
        return self._reflectance

    def _placement(self, rig):
        """Where the scene stands: the camera's placement, else the renders' default for ``rig``
        (:func:`~metrology.core.simulate.default_placement`)."""
        from metrology.core.simulate import default_placement

        return self.placement if self.placement is not None else default_placement(rig)

    def _cast(self, rig, scene, codec, opts):
        """A stereo rig's scene cast through both cameras (:func:`~metrology.core.simulate.stereo.cast_stereo`
        with the default projector, as :func:`~metrology.core.simulate.render_capture` casts it), once
        per acquisition: the geometry does not change with the exposure, only the light."""
        if self._stereo_cast is None:
            from metrology.core.codecs.model import gcps_v1_codec
            from metrology.core.simulate.stereo import cast_stereo

            where = self._placement(rig)
            self._stereo_cast = cast_stereo(rig, scene, codec or gcps_v1_codec(), where, supersample=opts.supersample)
        return self._stereo_cast

    def _hdr_cast(self, rig, scene, codec, opts):
        """A one-camera rig's HDR scene cast as :func:`~metrology.core.simulate.exposures.render_exposures`
        casts it (:func:`~metrology.core.simulate.exposures.cast_exposures`: the pixel centres' truth
        and the sub-pixel rays'), once per acquisition."""
        if self._camera_cast is None:
            from metrology.core.codecs.model import gcps_v1_codec
            from metrology.core.simulate.exposures import cast_exposures

            where = self._placement(rig)
            self._camera_cast = cast_exposures(rig, scene, codec or gcps_v1_codec(), opts.supersample, where)
        return self._camera_cast

    def _frames(self, rig, scene, codec, opts) -> tuple[np.ndarray, ...]:
        """Each camera's codec frames at this exposure (the HDR map's single-exposure render, else the plain one)."""
        from metrology.core.codecs.model import gcps_v1_codec
        from metrology.core.simulate import render_capture

        where = self._placement(rig)
        if self.hdr is None:
            if rig.cameras > 1:  # render_capture's stereo frames, from the kept cast
                from metrology.core.simulate.stereo import render_stereo_capture

                cast = self._cast(rig, scene, codec, opts)
                pair = render_stereo_capture(rig, scene, codec or gcps_v1_codec(), opts, placement=where, cast=cast)
                return pair.images
            return render_capture(rig, scene, codec, opts, placement=self.placement).camera_stacks
        from metrology.core.io.exposures import Exposure
        from metrology.core.simulate.exposures import render_exposures

        rho = self._hdr_reflectance(rig, scene, codec)
        if rig.cameras > 1:  # both cameras, one map over the scene (render_stereo_exposures)
            from metrology.core.simulate.exposures import render_stereo_exposures

            stereo = render_stereo_exposures(
                rig,
                scene,
                [Exposure("grab", 1000.0)],
                codec or gcps_v1_codec(),
                opts,
                placement=where,
                reflectance=rho,
                cast=self._cast(rig, scene, codec, opts),
            )
            return tuple(stack.images[0] for stack in stereo.stacks)
        rendered = render_exposures(
            rig,
            scene,
            [Exposure("grab", 1000.0)],
            codec,
            opts,
            reflectance=rho,
            placement=self.placement,
            cast=self._hdr_cast(rig, scene, codec, opts),
        )
        return (rendered.stack.images[0],)

    def _render(self, part: str) -> Any:
        """``"flats"`` (per camera, the white and black frames) or ``"stack"`` (per camera, the
        codec's frames, and their noise-free ``"clean"`` twins), rendered once per exposure."""
        if part in self._cache:
            return self._cache[part]
        if self.target is None:
            raise CameraError("the virtual camera was not prepared for an acquisition")
        from metrology.core.simulate import render_camera_flats, render_flats

        rig, scene, opts, codec = self._rig(), self._scene(), self._hdr_options(), self._codec()
        try:
            if part == "flats":
                if rig.cameras > 1:  # each camera under one map with HDR, as render_stereo_exposures
                    rho = None if self.hdr is None else self._hdr_reflectance(rig, scene, codec)
                    cast = self._cast(rig, scene, codec, opts)
                    pairs = render_camera_flats(rig, scene, opts, placement=self.placement, reflectance=rho, cast=cast)
                elif self.hdr is None:
                    pairs = render_camera_flats(rig, scene, opts, placement=self.placement)
                else:  # on the path of render_exposures, bounded by the codec's projector
                    rho, size = self._hdr_reflectance(rig, scene, codec), self._projector_size(codec)
                    rays = self._hdr_cast(rig, scene, codec, opts)[1]
                    pairs = (
                        render_flats(
                            rig, scene, opts, placement=self.placement, reflectance=rho, projector_size=size, rays=rays
                        ),
                    )
            else:
                self._cache["stack"] = self._frames(rig, scene, codec, opts)
                self._cache["clean"] = self._frames(rig, scene, codec, opts.with_changes(noise_grey=0.0))
                return self._cache[part]
        except ValueError as exc:
            raise CameraError(f"the virtual camera cannot render this acquisition: {exc}") from None
        flats = []
        for index, pair in enumerate(pairs):  # camera 0's noise as before the two-camera mode
            rng = np.random.default_rng([opts.seed, 4242, index] if index else [opts.seed, 4242])
            frames = {}
            for key, grey in zip(("white", "black"), pair, strict=True):
                noisy = grey + opts.noise_grey * rng.standard_normal(grey.shape) if opts.noise_grey > 0 else grey
                frames[key] = np.clip(np.rint(noisy), 0, opts.full_scale).astype(opts.dtype)
            flats.append(frames)
        self._cache["flats"] = flats
        return flats

    def grab(self, shown: Shown) -> tuple[np.ndarray, ...]:
        if shown.kind == "frame":
            return tuple(stack[shown.frame].copy() for stack in self._render("stack"))
        key = "white" if shown.kind == "white" else "black"
        return tuple(frames[key].copy() for frames in self._render("flats"))

    def expected(self, shown: Shown) -> tuple[np.ndarray | None, ...]:
        if shown.kind != "frame":
            return (None,) * self.camera_count
        self._render("stack")
        return tuple(stack[shown.frame] for stack in self._cache["clean"])

    def close(self) -> None:
        self._cache = {}


class FaultyCamera:
    """Wraps a rig's cameras and injects the faults a real rig shows into camera ``camera``'s frames,
    on a fixed schedule (for tests and demos).

    Every ``latency_every``-th grab returns, for that camera, the frame of the previously shown
    pattern (a camera whose frame was exposed before the projector switched); every
    ``saturate_every``-th grab a saturated frame (the frame times 4, clipped). 0 disables a fault.
    The other cameras' frames are left as grabbed.
    """

    def __init__(
        self, inner: Camera | RigCameras, latency_every: int = 0, saturate_every: int = 0, camera: int = 0
    ) -> None:
        if camera < 0:
            raise ValueError(f"the faulty camera's index must be 0 or more, got {camera}")
        self.inner = as_rig_cameras(inner)
        self.latency_every = latency_every
        self.saturate_every = saturate_every
        self.camera = camera
        on = f",camera={camera}" if camera else ""
        self.name = f"{self.inner.name}+faults(latency_every={latency_every},saturate_every={saturate_every}{on})"
        self.grabs = 0
        self.injected: list[tuple[int, str]] = []
        self._last: tuple[tuple[str, int], np.ndarray] | None = None  # (pattern, frame) of the last pattern
        self._previous: np.ndarray | None = None  # the frame of the pattern shown before it

    @property
    def camera_count(self) -> int:
        return self.inner.camera_count

    def open(self) -> None:
        self.inner.open()

    def prepare(self, target: AcquisitionTarget) -> None:
        self.inner.prepare(target)
        if self.camera >= self.inner.camera_count:
            raise CameraError(f"faults are injected on camera {self.camera}; the rig has {self.inner.camera_count}")
        self._last = self._previous = None

    def set_exposure(self, exposure_ms: float) -> None:
        self.inner.set_exposure(exposure_ms)

    def grab(self, shown: Shown) -> tuple[np.ndarray, ...]:
        frames = list(self.inner.grab(shown))
        frame = frames[self.camera]
        pattern = (shown.kind, shown.frame)
        if self._last is None or self._last[0] != pattern:
            self._previous = self._last[1] if self._last is not None else None
            self._last = (pattern, frame)
        self.grabs += 1
        if self.latency_every and self.grabs % self.latency_every == 0 and self._previous is not None:
            self.injected.append((self.grabs, "latency"))
            frames[self.camera] = self._previous.copy()
        elif self.saturate_every and self.grabs % self.saturate_every == 0:
            self.injected.append((self.grabs, "saturated"))
            top = np.iinfo(frame.dtype).max
            frames[self.camera] = np.minimum(frame.astype(np.uint32) * 4, top).astype(frame.dtype)
        return tuple(frames)

    def expected(self, shown: Shown) -> tuple[np.ndarray | None, ...]:
        return self.inner.expected(shown)

    def close(self) -> None:
        self.inner.close()


def make_camera(
    spec: str, *, scene: dict[str, Any] | None = None, options: dict[str, Any] | None = None
) -> Camera | RigCameras:
    """The camera backend named by ``spec`` (module docstring). Raises ``ValueError`` naming a bad spec."""
    kind, _, rest = spec.partition(":")
    if kind == "opencv":
        if not rest:
            raise ValueError("camera opencv needs a device: opencv:0, opencv:/dev/video2 or opencv:FILE.mp4")
        return OpenCVCamera(rest)
    if kind == "genicam":
        producer, _, index = (
            rest.rpartition(":") if rest.count(":") and rest.rsplit(":", 1)[1].isdigit() else (rest, "", "0")
        )
        if not producer:
            raise ValueError("camera genicam needs a GenTL producer: genicam:/path/to/producer.cti[:INDEX]")
        return GenICamCamera(producer, int(index or 0))
    if kind == "virtual":
        if rest:
            raise ValueError(
                "camera virtual takes no device; give the scene with --scene and options with --sim-options"
            )
        try:
            return VirtualCamera(scene, options)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"virtual camera options: {exc}") from None
    raise ValueError(f"camera {spec!r} is not known; use opencv:DEVICE, genicam:PRODUCER.cti or virtual")


def make_cameras(
    specs: Sequence[str],
    *,
    trigger_line: str | None = None,
    scene: dict[str, Any] | None = None,
    options: dict[str, Any] | None = None,
) -> RigCameras:
    """The rig's cameras named by ``specs``, camera 0 first: one spec (a one-camera rig's backend, or
    ``virtual``, which renders every camera of the rig), or two backends of a stereo rig
    (:class:`CameraPair`, hardware-triggered with ``trigger_line``). Raises ``ValueError`` naming a bad spec."""
    if len(specs) not in (1, 2):
        raise ValueError(f"give one camera per camera of the rig (1 or 2), got {len(specs)}")
    cameras = [make_camera(spec, scene=scene, options=options) for spec in specs]
    if len(cameras) == 1:
        if trigger_line is not None:
            raise ValueError("a trigger line synchronises the two cameras of a stereo rig: give --camera1 too")
        return as_rig_cameras(cameras[0])
    first, second = cameras
    if isinstance(first, RigCameras) or isinstance(second, RigCameras):
        raise ValueError("the virtual camera renders every camera of the rig: give --camera virtual alone")
    return CameraPair(first, second, trigger_line)
