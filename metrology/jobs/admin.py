from django.contrib import admin

from metrology.jobs.models import Job


@admin.register(Job)
class JobAdmin(admin.ModelAdmin):
    list_display = ("id", "kind", "status", "progress", "phase", "owner", "attempts", "created_at", "finished_at")
    list_filter = ("kind", "status", "owner")
    readonly_fields = ("run_token", "celery_task_id", "timings", "parameters", "software_version")
