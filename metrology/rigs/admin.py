from django.contrib import admin

from metrology.rigs.models import Rig, RigParameters


class RigParametersInline(admin.TabularInline):
    model = RigParameters
    extra = 0
    readonly_fields = ("values", "source", "calibration", "created_at")
    can_delete = False


@admin.register(Rig)
class RigAdmin(admin.ModelAdmin):
    list_display = ("id", "name", "owner", "model", "values")
    list_filter = ("owner", "model")
    search_fields = ("name", "notes")
    inlines = (RigParametersInline,)
    readonly_fields = ("model", "parameters")

    @admin.display(description="values")
    def values(self, rig: Rig) -> str:
        """The model's values in one line (:meth:`~metrology.core.geometry.base.GeometryModel.summary`)."""
        try:
            return rig.to_core().summary()
        except ValueError as exc:
            return f"unreadable: {exc}"
