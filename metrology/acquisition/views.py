"""Browser pages of acquisition: the projector page and the projector images it draws."""

from __future__ import annotations

import cv2
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.middleware.csrf import get_token
from django.shortcuts import render
from django.urls import reverse

from metrology.acquisition import services
from metrology.acquisition.models import Acquisition
from metrology.rigs.selectors import get_rig


@login_required
def projector_page(request: HttpRequest, rig_id: int) -> HttpResponse:
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
def projector_frame(request: HttpRequest, rig_id: int, acquisition_id: int, frame: int) -> HttpResponse:
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
