"""Capture agents, acquisition requests and the projector page's state, one row each."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class Agent(models.Model):
    """A ``gcps agent`` process registered for a rig; ``session`` identifies it in every call."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="capture_agents")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="agents")
    session = models.UUIDField(unique=True)
    name = models.CharField(max_length=200, blank=True, help_text="Host name or label the agent gave")
    camera = models.CharField(max_length=200, help_text="Camera backend and device, e.g. opencv:0")
    software_version = models.CharField(max_length=64, blank=True)
    connected_at = models.DateTimeField(auto_now_add=True)
    last_seen_at = models.DateTimeField()
    disconnected_at = models.DateTimeField(null=True, blank=True)
    disconnect_reason = models.CharField(max_length=300, blank=True)

    class Meta:
        ordering = ("-connected_at", "-id")

    def __str__(self) -> str:
        return f"agent {self.pk} ({self.camera}) on rig {self.rig_id}"


class Acquisition(models.Model):
    """A capture requested from a rig's agent: what to capture, who took it, what came back."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="acquisitions")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="acquisitions")
    session = models.ForeignKey("captures.CaptureSession", on_delete=models.CASCADE, related_name="acquisitions")
    role = models.CharField(max_length=16)
    z_in_mm = models.FloatField(null=True, blank=True)
    repeat = models.PositiveIntegerField(default=0)
    exposure_ms = models.FloatField(null=True, blank=True, help_text="Requested exposure, ms (None: automatic)")
    exposures = models.JSONField(
        null=True,
        blank=True,
        help_text='A multi-exposure capture: "auto" (bracketed by the agent) or exposure times, ms, shortest '
        "first (None: one exposure, or the agent's --exposures)",
    )
    max_exposures = models.PositiveSmallIntegerField(
        null=True, blank=True, help_text='Most exposures of an automatic bracket (exposures "auto"; None: the agent\'s)'
    )
    codec = models.JSONField(help_text='The codec: {"name": "gcps-v1:1024x768"} or a gcps-codec/1 document')
    job = models.OneToOneField("jobs.Job", on_delete=models.CASCADE, related_name="acquisition")
    agent = models.ForeignKey(Agent, null=True, blank=True, on_delete=models.SET_NULL, related_name="acquisitions")
    capture = models.OneToOneField(
        "captures.Capture", null=True, blank=True, on_delete=models.SET_NULL, related_name="acquisition"
    )
    frames = models.JSONField(default=list, blank=True, help_text="Per-frame checks reported by the agent")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("id",)

    def __str__(self) -> str:
        return f"acquisition {self.pk} ({self.role}) on rig {self.rig_id}"


class ProjectorState(models.Model):
    """What the rig's projector page is told to show (``seq``) and what it confirmed showing (``shown_*``).

    ``kind``: ``blank``, ``test``, ``white``, ``black`` or ``frame`` (frame ``frame`` of the
    acquisition's codec). The page confirms a pattern after the browser has painted it.
    """

    rig = models.OneToOneField("rigs.Rig", on_delete=models.CASCADE, primary_key=True, related_name="projector")
    seq = models.PositiveIntegerField(default=0)
    kind = models.CharField(max_length=16, default="blank")
    frame = models.IntegerField(default=-1)
    acquisition = models.ForeignKey(Acquisition, null=True, blank=True, on_delete=models.SET_NULL, related_name="+")
    shown_seq = models.PositiveIntegerField(default=0)
    shown_kind = models.CharField(max_length=16, blank=True)
    shown_frame = models.IntegerField(default=-1)
    shown_at = models.DateTimeField(null=True, blank=True)
    screen = models.JSONField(default=dict, blank=True, help_text="The page's screen: CSS size, device pixel ratio")
    page_seen_at = models.DateTimeField(null=True, blank=True)

    def __str__(self) -> str:
        return f"projector of rig {self.rig_id}: {self.kind} {self.frame} (seq {self.seq}, shown {self.shown_seq})"
