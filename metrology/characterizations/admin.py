from django.contrib import admin

from metrology.characterizations.models import Characterization


@admin.register(Characterization)
class CharacterizationAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "overall_mean_error_mm", "overall_std_error_mm", "job", "owner", "created_at")
    list_filter = ("owner",)
    readonly_fields = ("series", "results", "parameters", "rig_values")
