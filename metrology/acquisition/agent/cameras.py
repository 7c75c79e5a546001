"""Camera backends behind one small interface: OpenCV ``VideoCapture``, GenICam (``harvesters``), the virtual rig.

A backend is named on the command line by a spec:

- ``opencv:0`` (device index), ``opencv:/dev/video2`` or ``opencv:FILE.mp4`` (a video file, for
  testing: each grab reads the next frame);
- ``genicam:PRODUCER.cti[:INDEX]`` (GenICam/GigE Vision/USB3 Vision through the optional
  ``harvesters`` package);
- ``virtual`` (the virtual rig, :mod:`metrology.core.simulate`, through the rig's own model: it
  renders what the camera would see under the pattern the projector REPORTS it shows).

Frames are single-channel ``(H, W)`` uint8 or uint16 arrays (colour cameras are converted to grey).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

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


class GenICamCamera:
    """A GenICam camera (GigE Vision, USB3 Vision) through ``harvesters`` and a vendor GenTL producer (.cti)."""

    def __init__(self, producer: str, index: int = 0) -> None:
        self.producer = producer
        self.index = index
        self.name = f"genicam:{producer}:{index}"
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
        harvester = Harvester()
        harvester.add_file(self.producer)
        harvester.update()
        if len(harvester.device_info_list) <= self.index:
            harvester.reset()
            raise CameraError(f"camera {self.name}: {len(harvester.device_info_list)} GenICam device(s) found")
        self._harvester = harvester
        self._acquirer = harvester.create(self.index)
        self._acquirer.start()

    def prepare(self, target: AcquisitionTarget) -> None:
        return None

    def set_exposure(self, exposure_ms: float) -> None:
        try:
            self._acquirer.remote_device.node_map.ExposureTime.value = float(exposure_ms) * 1000.0  # microseconds
        except Exception as exc:
            raise CameraError(f"camera {self.name} refused exposure {exposure_ms} ms: {exc}") from None

    def grab(self, shown: Shown) -> np.ndarray:
        with self._acquirer.fetch(timeout=10) as buffer:
            component = buffer.payload.components[0]
            frame = np.array(component.data, copy=True).reshape(component.height, component.width, -1)
        return _grey(frame)

    def expected(self, shown: Shown) -> np.ndarray | None:
        return None

    def close(self) -> None:
        if self._acquirer is not None:
            self._acquirer.stop()
            self._acquirer.destroy()
        if self._harvester is not None:
            self._harvester.reset()
        self._acquirer = self._harvester = None


class VirtualCamera:
    """The virtual rig as a camera: the frame the camera would see under the pattern the projector reports.

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

    def open(self) -> None:
        return None

    def prepare(self, target: AcquisitionTarget) -> None:
        if not target.rig_geometry:
            raise CameraError("the virtual camera needs the rig's geometry")
        self.target = target
        try:
            self._rig()
        except ValueError as exc:
            raise CameraError(f"the virtual camera cannot render this rig: {exc}") from None
        self._cache = {}
        self._reflectance = None

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

    def _frames(self, rig, scene, codec, opts) -> np.ndarray:
        """The codec's frames at this exposure (the HDR map's single-exposure render, else the plain one)."""
        from metrology.core.simulate import render_capture

        if self.hdr is None:
            return render_capture(rig, scene, codec, opts, placement=self.placement).images
        from metrology.core.io.exposures import Exposure
        from metrology.core.simulate.exposures import render_exposures

        rho = self._hdr_reflectance(rig, scene, codec)
        rendered = render_exposures(
            rig, scene, [Exposure("grab", 1000.0)], codec, opts, reflectance=rho, placement=self.placement
        )
        return rendered.stack.images[0]

    def _render(self, part: str) -> Any:
        """``"flats"`` (white and black frames) or ``"stack"`` (the codec's frames and their
        noise-free ``"clean"`` twins), rendered once per exposure."""
        if part in self._cache:
            return self._cache[part]
        if self.target is None:
            raise CameraError("the virtual camera was not prepared for an acquisition")
        from metrology.core.simulate import render_flats

        rig, scene, opts, codec = self._rig(), self._scene(), self._hdr_options(), self._codec()
        try:
            if part == "flats":
                if self.hdr is None:
                    white, black = render_flats(rig, scene, opts, placement=self.placement)
                else:  # on the path of render_exposures, bounded by the codec's projector
                    rho, size = self._hdr_reflectance(rig, scene, codec), self._projector_size(codec)
                    white, black = render_flats(
                        rig, scene, opts, placement=self.placement, reflectance=rho, projector_size=size
                    )
            else:
                self._cache["stack"] = self._frames(rig, scene, codec, opts)
                self._cache["clean"] = self._frames(rig, scene, codec, opts.with_changes(noise_grey=0.0))
                return self._cache[part]
        except ValueError as exc:
            raise CameraError(f"the virtual camera cannot render this acquisition: {exc}") from None
        rng = np.random.default_rng([opts.seed, 4242])
        flats = {}
        for key, grey in (("white", white), ("black", black)):
            noisy = grey + opts.noise_grey * rng.standard_normal(grey.shape) if opts.noise_grey > 0 else grey
            flats[key] = np.clip(np.rint(noisy), 0, opts.full_scale).astype(opts.dtype)
        self._cache["flats"] = flats
        return flats

    def grab(self, shown: Shown) -> np.ndarray:
        if shown.kind == "frame":
            return self._render("stack")[shown.frame].copy()
        flats = self._render("flats")
        return (flats["white"] if shown.kind == "white" else flats["black"]).copy()

    def expected(self, shown: Shown) -> np.ndarray | None:
        if shown.kind != "frame":
            return None
        self._render("stack")
        return self._cache["clean"][shown.frame]

    def close(self) -> None:
        self._cache = {}


class FaultyCamera:
    """Wraps a camera and injects the faults a real rig shows, on a fixed schedule (for tests and demos).

    Every ``latency_every``-th grab returns the frame of the previously shown pattern (a camera
    whose frame was exposed before the projector switched); every ``saturate_every``-th grab
    returns a saturated frame (the frame times 4, clipped). 0 disables a fault.
    """

    def __init__(self, inner: Camera, latency_every: int = 0, saturate_every: int = 0) -> None:
        self.inner = inner
        self.latency_every = latency_every
        self.saturate_every = saturate_every
        self.name = f"{inner.name}+faults(latency_every={latency_every},saturate_every={saturate_every})"
        self.grabs = 0
        self.injected: list[tuple[int, str]] = []
        self._last: tuple[tuple[str, int], np.ndarray] | None = None  # (pattern, frame) of the last pattern
        self._previous: np.ndarray | None = None  # the frame of the pattern shown before it

    def open(self) -> None:
        self.inner.open()

    def prepare(self, target: AcquisitionTarget) -> None:
        self.inner.prepare(target)
        self._last = self._previous = None

    def set_exposure(self, exposure_ms: float) -> None:
        self.inner.set_exposure(exposure_ms)

    def grab(self, shown: Shown) -> np.ndarray:
        frame = self.inner.grab(shown)
        pattern = (shown.kind, shown.frame)
        if self._last is None or self._last[0] != pattern:
            self._previous = self._last[1] if self._last is not None else None
            self._last = (pattern, frame)
        self.grabs += 1
        if self.latency_every and self.grabs % self.latency_every == 0 and self._previous is not None:
            self.injected.append((self.grabs, "latency"))
            return self._previous.copy()
        if self.saturate_every and self.grabs % self.saturate_every == 0:
            self.injected.append((self.grabs, "saturated"))
            top = np.iinfo(frame.dtype).max
            return np.minimum(frame.astype(np.uint32) * 4, top).astype(frame.dtype)
        return frame

    def expected(self, shown: Shown) -> np.ndarray | None:
        return self.inner.expected(shown)

    def close(self) -> None:
        self.inner.close()


def make_camera(spec: str, *, scene: dict[str, Any] | None = None, options: dict[str, Any] | None = None) -> Camera:
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
