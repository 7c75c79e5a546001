"""Report pages: /reports/ (list), /reports/<id>/ (detail), its HTML inline and as a download."""

from django.urls import path

from metrology.reports import views

app_name = "reports"

urlpatterns = [
    path("", views.report_list, name="list"),
    path("run/", views.report_run, name="run"),
    path("schedule/", views.report_schedule, name="schedule"),
    path("schedule/<int:rig_id>/run/", views.report_schedule_run, name="schedule-run"),
    path("schedule/<int:rig_id>/delete/", views.report_schedule_delete, name="schedule-delete"),
    path("<int:report_id>/", views.report_detail, name="detail"),
    path("<int:report_id>/report.html", views.report_html, name="html"),
    path("<int:report_id>/download/", views.report_download, name="download"),
]
