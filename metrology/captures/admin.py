from django.contrib import admin

from metrology.captures.models import Capture, CaptureSession


@admin.register(CaptureSession)
class CaptureSessionAdmin(admin.ModelAdmin):
    list_display = ("id", "name", "rig", "owner", "created_at")
    list_filter = ("owner",)


@admin.register(Capture)
class CaptureAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "session", "role", "z_in_mm", "repeat", "source", "bit_depth", "created_at")
    list_filter = ("role", "source", "owner")
    readonly_fields = ("checksum_sha256", "size_bytes", "job")
