"""The HTTP side of ``gcps agent``: the server's agent protocol (docs/acquisition.md) and the agent's loop."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import signal
import socket
import threading
import time
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import requests

from metrology.acquisition.agent.bracketing import Bracket, BracketOptions, ExposureChoice, parse_exposures
from metrology.acquisition.agent.cameras import AcquisitionTarget, Camera, CameraError, RigCameras, Shown
from metrology.acquisition.agent.patterns import ProjectedCodec, resolve_codec
from metrology.acquisition.agent.sequencer import (
    AcquisitionError,
    Progress,
    Projector,
    SequenceOptions,
    run_bracketed_sequence,
    run_sequence,
)
from metrology.core.io.images import encode_params

logger = logging.getLogger(__name__)


class ProtocolError(Exception):
    """The server refused a call (the message is its ``error``)."""

    def __init__(self, message: str, status: int = 0) -> None:
        super().__init__(message)
        self.status = status


class AgentClient:
    """Calls of the agent protocol, authenticated with the user's API token."""

    def __init__(self, server: str, token: str, rig: int, timeout_s: float = 30.0) -> None:
        self.base = server.rstrip("/")
        self.rig = rig
        self.timeout_s = timeout_s
        self.http = requests.Session()
        self.http.headers["Authorization"] = f"Token {token}"
        self.session: str | None = None
        self.lock = threading.Lock()  # requests.Session is shared with the heartbeat thread

    def _call(self, method: str, path: str, *, timeout: float | None = None, **kwargs: Any) -> requests.Response:
        url = f"{self.base}/api/{path.lstrip('/')}"
        try:
            with self.lock:
                response = self.http.request(method, url, timeout=timeout or self.timeout_s, **kwargs)
        except requests.RequestException as exc:
            raise ProtocolError(f"cannot reach the server {self.base}: {exc}") from None
        if response.status_code >= 400:
            try:
                message = response.json().get("error", response.text)
            except ValueError:
                message = response.text[:300]
            raise ProtocolError(f"{method} {path}: HTTP {response.status_code}: {message}", response.status_code)
        return response

    def register(self, camera: str, version: str) -> dict[str, Any]:
        body = self._call(
            "POST",
            f"rigs/{self.rig}/agent/register/",
            json={"camera": camera, "name": socket.gethostname(), "software_version": version},
        ).json()
        self.session = body["session"]
        return body

    def heartbeat(self) -> None:
        self._call("POST", f"rigs/{self.rig}/agent/heartbeat/", json={"session": self.session})

    def disconnect(self, reason: str) -> None:
        self._call("POST", f"rigs/{self.rig}/agent/disconnect/", json={"session": self.session, "reason": reason})

    def take(self) -> dict[str, Any] | None:
        response = self._call("POST", f"rigs/{self.rig}/agent/take/", json={"session": self.session})
        return None if response.status_code == 204 else response.json()

    def progress(self, acquisition: int, percent: int, phase: str, frames: list | None = None) -> None:
        self._call(
            "POST",
            f"acquisitions/{acquisition}/progress/",
            json={"session": self.session, "percent": percent, "phase": phase, "frames": frames},
        )

    def fail(self, acquisition: int, reason: str, frames: list | None = None) -> None:
        self._call(
            "POST",
            f"acquisitions/{acquisition}/fail/",
            json={"session": self.session, "reason": reason, "frames": frames},
        )

    def upload(self, acquisition: int, zip_bytes: bytes, *, camera: str, exposure_ms: float | None, frames: list):
        data = {"session": self.session, "camera": camera, "frames": json.dumps(frames)}
        if exposure_ms is not None:
            data["exposure_ms"] = repr(float(exposure_ms))
        return self._call(
            "POST",
            f"acquisitions/{acquisition}/upload/",
            data=data,
            files={"file": (f"acquisition-{acquisition}.zip", zip_bytes, "application/zip")},
            timeout=max(self.timeout_s, 120.0),
        ).json()


class ServerProjector:
    """The rig's projector page, driven through the server: show, then long-poll until the page confirms."""

    def __init__(self, client: AgentClient, acquisition: int | None, confirm_timeout_s: float = 30.0) -> None:
        self.client = client
        self.acquisition = acquisition
        self.confirm_timeout_s = confirm_timeout_s

    def show(self, kind: str, frame: int = -1) -> Shown:
        body: dict[str, Any] = {"session": self.client.session, "kind": kind, "frame": frame}
        if kind == "frame":
            body["acquisition"] = self.acquisition
        seq = self.client._call("POST", f"rigs/{self.client.rig}/projector/", json=body).json()["seq"]
        deadline = time.monotonic() + self.confirm_timeout_s
        while time.monotonic() < deadline:
            wait = min(10.0, max(0.1, deadline - time.monotonic()))
            state = self.client._call(
                "GET", f"rigs/{self.client.rig}/projector/?shown={seq}&wait={wait:.1f}", timeout=wait + 30
            ).json()
            if state["shown_seq"] >= seq:
                if state["shown_seq"] > seq:
                    raise AcquisitionError(f"the projector moved past pattern {seq}: another agent drives it?")
                return Shown(kind=state["shown_kind"], frame=state["shown_frame"], seq=seq)
        raise AcquisitionError(
            f"the projector page did not confirm {kind} {frame if kind == 'frame' else ''} within "
            f"{self.confirm_timeout_s:.0f} s: is {self.client.base}/rigs/{self.client.rig}/projector/ open "
            "on the projector's screen?"
        )


def stack_zip(images: np.ndarray, codec: ProjectedCodec) -> bytes:
    """The frames as a zip of PNGs named as the codec says (gcps-v1: GC_0.png ... PS_3.png)."""
    return exposures_zip([images], None, codec)


def cameras_zip(stacks: Sequence[np.ndarray], codec: ProjectedCodec) -> bytes:
    """One stack per camera of the rig, camera 0 first: a one-camera rig's as :func:`stack_zip`;
    a stereo rig's capture (docs/stereo.md) with each camera's frames in ``cam0/``, ``cam1/`` ...
    and ``codec.json`` at the top for a codec other than gcps-v1."""
    from metrology.core.io.cameras import camera_folders

    if len(stacks) == 1:
        return stack_zip(stacks[0], codec)
    return _frames_zip([f"{folder}/" for folder in camera_folders(len(stacks))], stacks, codec)


def exposures_zip(
    stacks: Sequence[np.ndarray | Sequence[np.ndarray]], exposures_ms: list[float] | None, codec: ProjectedCodec
) -> bytes:
    """One stack's frames as a zip of PNGs named as the codec says (``exposures_ms`` None), or a
    multi-exposure capture (docs/exposures.md): ``exposures.json`` and the frames of exposure ``i``
    in ``exp<i>/``; ``codec.json`` at the top for a codec other than gcps-v1. A stack of exposure
    ``i`` given as a sequence of one stack per camera (a stereo rig) goes to ``cam<c>/exp<i>/``
    (docs/exposures.md, "Stereo rigs")."""
    from metrology.core.io.cameras import camera_folder
    from metrology.core.io.exposures import Exposure, exposures_json

    if exposures_ms is None:
        return _frames_zip([""], stacks, codec)  # type: ignore[arg-type]
    entries = [Exposure(f"exp{i}", float(e) * 1000.0) for i, e in enumerate(exposures_ms)]
    folders: list[str] = []
    flat: list[np.ndarray] = []
    for i, stack in enumerate(stacks):
        if isinstance(stack, np.ndarray):
            folders.append(f"exp{i}/")
            flat.append(stack)
            continue
        for c, images in enumerate(stack):  # one stack per camera
            folders.append(f"{camera_folder(c)}/exp{i}/")
            flat.append(images)
    return _frames_zip(folders, flat, codec, {"exposures.json": exposures_json(entries)})


def _frames_zip(
    folders: Sequence[str], stacks: Sequence[np.ndarray], codec: ProjectedCodec, extra: dict[str, str] | None = None
) -> bytes:
    """A zip of ``extra``'s files, then each stack's frames as PNGs named as the codec says in its
    folder (``""``: the top), then ``codec.json`` for a codec other than gcps-v1."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, text in (extra or {}).items():
            archive.writestr(name, text)
        for folder, images in zip(folders, stacks, strict=True):
            for name, image in zip(codec.frame_names, images, strict=True):
                ok, data = cv2.imencode(".png", image, encode_params(".png"))
                if not ok:
                    raise AcquisitionError(f"cannot encode frame {name} as PNG")
                archive.writestr(folder + (f"{name}.png" if "." not in name else name), data.tobytes())
        if not codec.is_gcps_v1:
            archive.writestr("codec.json", codec.spec)
    return buffer.getvalue()


@dataclass
class AcquiredCapture:
    """What one acquisition gives to upload or write: ``data``, the capture's zip (one stack, a
    stereo capture, or a multi-exposure capture); ``exposure_ms``, the single stack's exposure or
    the shortest of several; ``exposures_ms``, every exposure, shortest first (None for a single
    stack); ``reports``, each accepted frame's checks; ``bracket``, the automatic bracket (or None)."""

    data: bytes
    exposure_ms: float | None
    exposures_ms: list[float] | None
    reports: list[dict[str, Any]]
    bracket: Bracket | None = None


def acquire_capture(
    projector: Projector,
    camera: Camera | RigCameras,
    codec: ProjectedCodec,
    *,
    exposure_ms: float | None = None,
    exposures: ExposureChoice | None = None,
    bracket: BracketOptions | None = None,
    options: SequenceOptions | None = None,
    progress: Progress | None = None,
) -> AcquiredCapture:
    """Acquire one capture as ``gcps agent`` and ``gcps capture`` write it (docs/acquisition.md).

    ``exposures`` None: one stack (per camera) at ``exposure_ms`` (None: the auto-exposure),
    :func:`~.sequencer.run_sequence`; ``"auto"`` or times in ms: a multi-exposure capture
    (docs/exposures.md), :func:`~.sequencer.run_bracketed_sequence`, written as ``exposures.json``
    and ``exp0/``, ``exp1/``, ... (``cam0/exp0/`` ... on a stereo rig). Raises
    :class:`~.sequencer.AcquisitionError` with the reason.
    """
    if exposures is None:
        result = run_sequence(projector, camera, codec, exposure_ms=exposure_ms, options=options, progress=progress)
        return AcquiredCapture(
            cameras_zip(result.camera_stacks, codec), result.exposure_ms, None, result.frame_reports()
        )
    bracketed = run_bracketed_sequence(
        projector,
        camera,
        codec,
        exposures_ms=None if isinstance(exposures, str) else exposures,
        bracket_options=bracket,
        options=options,
        progress=progress,
    )
    times = list(bracketed.exposures_ms)
    reports = [report for stack in bracketed.stacks for report in stack.frame_reports()]
    per_exposure = [s.images if len(s.camera_stacks) == 1 else s.camera_stacks for s in bracketed.stacks]
    data = exposures_zip(per_exposure, times, codec)
    return AcquiredCapture(data, times[0], times, reports, bracketed.bracket)


@dataclass
class AgentOptions:
    sequence: SequenceOptions
    poll_s: float = 1.0
    max_acquisitions: int = 0  # 0: run until stopped
    confirm_timeout_s: float = 30.0
    exposures: ExposureChoice | None = None
    """None: one stack per acquisition; ``"auto"``: an automatic bracket; a tuple: those exposures, ms
    (multi-exposure captures, docs/exposures.md). The default of the requests that choose neither
    ``exposures`` nor ``exposure`` (:func:`requested_exposures`)."""
    bracket: BracketOptions = field(default_factory=BracketOptions)


class _Heartbeat(threading.Thread):
    def __init__(self, client: AgentClient, period_s: float) -> None:
        super().__init__(name="gcps-agent-heartbeat", daemon=True)
        self.client = client
        self.period_s = period_s
        self.stop_event = threading.Event()
        self.error: str | None = None

    def run(self) -> None:
        while not self.stop_event.wait(self.period_s):
            try:
                self.client.heartbeat()
            except ProtocolError as exc:
                self.error = str(exc)
                if exc.status == 409:  # the server disconnected this session
                    return


class _StopRequestedError(Exception):
    pass


def run_agent(client: AgentClient, camera: RigCameras, options: AgentOptions, version: str) -> dict[str, Any]:
    """Register, then take and run acquisitions until stopped (SIGTERM/SIGINT) or ``max_acquisitions`` are done.

    Returns a summary. Raises :class:`ProtocolError` when registration is refused.
    """
    camera.open()
    registered = client.register(camera.name, version)
    heartbeat = _Heartbeat(client, float(registered.get("heartbeat_seconds", 5.0)))
    heartbeat.start()
    done: list[dict[str, Any]] = []
    stop_reason = ""

    def on_signal(signum: int, _frame: Any) -> None:
        raise _StopRequestedError(f"agent stopped ({signal.Signals(signum).name})")

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        while not options.max_acquisitions or len(done) < options.max_acquisitions:
            if heartbeat.error and "409" in heartbeat.error:
                raise ProtocolError(f"the server dropped this agent: {heartbeat.error}", 409)
            acquisition = client.take()
            if acquisition is None:
                time.sleep(options.poll_s)
                continue
            done.append(_run_one(client, camera, acquisition, options))
        stop_reason = "the capture agent finished its acquisitions"
    except _StopRequestedError as exc:
        stop_reason = str(exc)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        heartbeat.stop_event.set()
        camera.close()
        with contextlib.suppress(ProtocolError):
            client.disconnect(stop_reason or "the capture agent stopped on an error")
    return {"agent": registered.get("id"), "camera": camera.name, "acquisitions": done, "stopped": stop_reason}


def requested_exposures(
    acquisition: dict[str, Any], options: AgentOptions
) -> tuple[ExposureChoice | None, BracketOptions]:
    """The exposures of one acquisition and the automatic bracket's options: the request's choice
    (``exposures``: ``"auto"`` with its ``max_exposures``, or times in ms; or one ``exposure_ms``)
    over the agent's ``--exposures`` / ``--max-exposures``, which serve requests that choose nothing."""
    bracket = options.bracket
    if acquisition.get("max_exposures"):
        bracket = dataclasses.replace(bracket, max_exposures=int(acquisition["max_exposures"]))
    if acquisition.get("exposures") is not None:
        return parse_exposures(acquisition["exposures"]), bracket
    if acquisition.get("exposure_ms") is not None:
        return None, bracket
    return options.exposures, bracket


def _run_one(client: AgentClient, camera: RigCameras, acquisition: dict[str, Any], options: AgentOptions) -> dict:
    acq_id = int(acquisition["id"])
    frames: list[dict[str, Any]] = []

    def progress(percent: int, phase: str, checks: list[dict[str, Any]]) -> None:
        frames[:] = checks
        client.progress(acq_id, percent, phase, checks)

    try:
        codec = resolve_codec(acquisition["codec"])
        camera.prepare(
            AcquisitionTarget(
                role=acquisition["role"],
                z_in_mm=acquisition.get("z_in_mm"),
                repeat=int(acquisition.get("repeat") or 0),
                codec=codec,
                rig_geometry=acquisition.get("rig_geometry") or {},
            )
        )
        projector = ServerProjector(client, acq_id, options.confirm_timeout_s)
        exposures, bracket = requested_exposures(acquisition, options)
        acquired = acquire_capture(
            projector,
            camera,
            codec,
            exposure_ms=acquisition.get("exposure_ms"),
            exposures=exposures,
            bracket=bracket,
            options=options.sequence,
            progress=progress,
        )
        client.progress(acq_id, 97, "uploading", acquired.reports)
        body = client.upload(
            acq_id, acquired.data, camera=camera.name, exposure_ms=acquired.exposure_ms, frames=acquired.reports
        )
        return {
            "acquisition": acq_id,
            "status": "done",
            "capture": body.get("capture"),
            "exposures_ms": acquired.exposures_ms,
        }
    except (AcquisitionError, CameraError, ValueError) as exc:
        reason = str(exc)
    except ProtocolError as exc:
        if exc.status == 409:  # the acquisition was failed server-side (timeout); nothing to report
            return {"acquisition": acq_id, "status": "refused", "error": str(exc)}
        reason = f"the agent could not complete the protocol: {exc}"
    logger.warning("acquisition %s failed: %s", acq_id, reason)
    with contextlib.suppress(ProtocolError):
        client.fail(acq_id, reason, frames)
    return {"acquisition": acq_id, "status": "failed", "error": reason}
