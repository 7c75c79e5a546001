from django.contrib import admin

from metrology.calibrations.models import Calibration, ProcamCalibration


@admin.register(Calibration)
class CalibrationAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "method", "master_height_mm", "applied", "job", "owner", "created_at")
    list_filter = ("method", "applied", "owner")
    readonly_fields = ("iterations", "result", "parameters", "rig_values")


@admin.register(ProcamCalibration)
class ProcamCalibrationAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "board", "applied", "job", "owner", "created_at")
    list_filter = ("applied", "owner")
    readonly_fields = ("options", "report", "report_json", "rig_file", "rig_before")
