from django.contrib import admin

from metrology.reports.models import Report


@admin.register(Report)
class ReportAdmin(admin.ModelAdmin):
    list_display = ("id", "rig", "source", "status", "drift_beyond", "characterization", "owner", "created_at")
    list_filter = ("source", "owner")
    list_select_related = ("rig", "job", "owner")
    readonly_fields = ("parameters", "summary", "drift", "job", "characterization", "session", "previous", "html")

    @admin.display(description="status")
    def status(self, report: Report) -> str:
        return report.job.status

    @admin.display(description="drifted figures")
    def drift_beyond(self, report: Report) -> int:
        return int(report.drift.get("beyond", 0))
