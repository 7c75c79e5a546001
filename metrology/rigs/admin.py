from django.contrib import admin

from metrology.rigs.models import Rig, RigParameters


class RigParametersInline(admin.TabularInline):
    model = RigParameters
    extra = 0
    readonly_fields = ("values", "source", "calibration", "created_at")
    can_delete = False


@admin.register(Rig)
class RigAdmin(admin.ModelAdmin):
    list_display = ("id", "name", "owner", "L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")
    list_filter = ("owner",)
    search_fields = ("name", "notes")
    inlines = (RigParametersInline,)
