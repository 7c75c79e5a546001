"""Browser pages of acquisition: the projector page and the projector images it draws."""

from __future__ import annotations

import cv2
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpResponse
from django.middleware.csrf import get_token
from django.shortcuts import redirect, render
from django.urls import reverse

from metrology.accounts.http import AuthenticatedHttpRequest
from metrology.acquisition import services
from metrology.acquisition.forms import AcquireForm
from metrology.acquisition.models import Acquisition, Agent
from metrology.captures.codecs import codec_label
from metrology.errors import DomainError
from metrology.rigs.selectors import get_rig

THUMBNAIL_WIDTH = 160


@login_required
def projector_page(request: AuthenticatedHttpRequest, rig_id: int) -> HttpResponse:
    """Full-screen, pixel-exact pattern display for the rig's projector (JS: static/acquisition/projector.js).

    ``?webcam=1`` is the zero-install webcam mode (static/acquisition/webcam.js): the page is also
    the rig's capture agent, grabbing frames from a webcam through the browser (``?settle=MS``).
    """
    rig = get_rig(request.user, rig_id)
    services.projector_state(rig)
    frame_url = reverse("acquisition:projector-frame", args=[rig.pk, 999999001, 999999002])
    mode = "webcam" if request.GET.get("webcam") else "projector"
    try:
        settle_ms = max(0, min(10_000, int(request.GET.get("settle", "300"))))
    except ValueError:
        settle_ms = 300
    acq = 999999001

    def acquisition_url(name: str) -> str:
        return reverse(name, args=[acq]).replace(str(acq), "{id}")

    agent_urls = {
        "register": reverse("api-rig-agent-register", args=[rig.pk]),
        "heartbeat": reverse("api-rig-agent-heartbeat", args=[rig.pk]),
        "take": reverse("api-rig-agent-take", args=[rig.pk]),
        "disconnect": reverse("api-rig-agent-disconnect", args=[rig.pk]),
        "progress": acquisition_url("api-acquisition-progress"),
        "fail": acquisition_url("api-acquisition-fail"),
        "upload": acquisition_url("api-acquisition-upload"),
    }
    return render(
        request,
        "acquisition/projector.html",
        {
            "rig": rig,
            "state_url": reverse("api-rig-projector", args=[rig.pk]),
            "shown_url": reverse("api-rig-projector-shown", args=[rig.pk]),
            "frame_url": frame_url.replace("999999001", "{acquisition}").replace("999999002", "{frame}"),
            "csrf": get_token(request),
            "mode": mode,
            "settle_ms": settle_ms,
            "agent_urls": agent_urls,
        },
    )


@login_required
def projector_frame(request: AuthenticatedHttpRequest, rig_id: int, acquisition_id: int, frame: int) -> HttpResponse:
    """Frame ``frame`` of the acquisition's codec as a grey PNG at the projector's resolution."""
    rig = get_rig(request.user, rig_id)
    acquisition = Acquisition.objects.filter(pk=acquisition_id, rig=rig, owner=request.user).first()
    if acquisition is None:
        raise Http404(f"No acquisition {acquisition_id} on rig {rig.pk}.")
    images = services.codec_of(acquisition).images()
    if not 0 <= frame < images.shape[0]:
        raise Http404(f"No frame {frame} in this codec (0..{images.shape[0] - 1}).")
    ok, data = cv2.imencode(".png", images[frame])
    if not ok:  # pragma: no cover - OpenCV cannot fail on a uint8 image
        raise RuntimeError("PNG encoding failed")
    response = HttpResponse(data.tobytes(), content_type="image/png")
    response["Cache-Control"] = "private, max-age=3600"
    return response


def _own_acquisition(request: AuthenticatedHttpRequest, acquisition_id: int) -> Acquisition:
    acquisition = (
        Acquisition.objects.select_related("job", "rig", "agent", "capture")
        .filter(pk=acquisition_id, owner=request.user)
        .first()
    )
    if acquisition is None:
        raise Http404(f"No acquisition {acquisition_id} among yours.")
    return acquisition


@login_required
def acquire_page(request: AuthenticatedHttpRequest, rig_id: int) -> HttpResponse:
    """Acquire from the rig: the agent's status, the request form, the rig's acquisitions."""
    rig = get_rig(request.user, rig_id)
    form = AcquireForm(request.POST or None)
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        try:
            acquisition = services.request_acquisition(
                owner=request.user,
                rig=rig,
                role=data["role"],
                z_in_mm=data.get("z_in_mm"),
                repeat=data.get("repeat") or 0,
                exposure_ms=data.get("exposure"),
                exposures=data.get("exposures"),
                max_exposures=data.get("max_exposures"),
                codec=data.get("codec") or None,
            )
        except DomainError as exc:
            form.add_error(None, str(exc))
        else:
            return redirect("acquisition:acquisition", acquisition.pk)
    agent = services.connected_agent(rig) or Agent.objects.filter(rig=rig).order_by("-connected_at").first()
    return render(
        request,
        "acquisition/acquire.html",
        {
            "rig": rig,
            "form": form,
            "agent": agent,
            "acquisitions": Acquisition.objects.filter(rig=rig, owner=request.user)
            .select_related("job")
            .order_by("-id")[:50],
        },
        status=400 if request.method == "POST" else 200,
    )


@login_required
def acquisition_page(request: AuthenticatedHttpRequest, acquisition_id: int) -> HttpResponse:
    """One acquisition: live progress, the agent, each frame's checks and (once stored) its thumbnail."""
    acquisition = _own_acquisition(request, acquisition_id)
    services.expire_agents(acquisition.rig)
    acquisition.refresh_from_db()
    acquisition.job.refresh_from_db()
    frames = [f for f in acquisition.frames if isinstance(f, dict)]
    names = list(services.codec_of(acquisition).frame_names)
    for entry in frames:
        name = entry.get("name")
        entry["index"] = names.index(name) if acquisition.capture_id and name in names else None
    return render(
        request,
        "acquisition/acquisition.html",
        {
            "acquisition": acquisition,
            "job": acquisition.job,
            "rig": acquisition.rig,
            "frames": frames,
            "codec_label": codec_label(services.stored_codec_value(acquisition)),
        },
    )


@login_required
def acquisition_thumbnail(request: AuthenticatedHttpRequest, acquisition_id: int, frame: int) -> HttpResponse:
    """Frame ``frame`` of the stored capture (of camera ``?camera=K`` on a rig of several cameras,
    default 0), 160 px wide (area-averaged), PNG."""
    acquisition = _own_acquisition(request, acquisition_id)
    if acquisition.capture is None:
        raise Http404("This acquisition has no stored capture.")
    from metrology.captures.stacks import load_capture_images

    images = load_capture_images(acquisition.capture)
    if isinstance(images, tuple):  # one stack per camera, camera 0 first
        camera = request.GET.get("camera", "0")
        if not camera.isdigit() or int(camera) >= len(images):
            raise Http404(f"No camera {camera}.")
        images = images[int(camera)]
    if not 0 <= frame < images.shape[0]:
        raise Http404(f"No frame {frame}.")
    image = images[frame]
    if image.dtype != "uint8":
        image = (image >> 8).astype("uint8")
    height, width = image.shape
    if width > THUMBNAIL_WIDTH:
        size = (THUMBNAIL_WIDTH, max(1, round(height * THUMBNAIL_WIDTH / width)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    _ok, data = cv2.imencode(".png", image)
    response = HttpResponse(data.tobytes(), content_type="image/png")
    response["Cache-Control"] = "private, max-age=3600"
    return response
