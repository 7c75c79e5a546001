from django.contrib import admin

from metrology.measurements.models import Measurement


@admin.register(Measurement)
class MeasurementAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "reference", "object", "job", "owner", "created_at")
    list_filter = ("owner",)
    readonly_fields = ("statistics", "rig_values")
