"""Browser pages (server-rendered), mounted at the site root."""

from django.contrib.auth import views as auth_views
from django.urls import path

from metrology.dashboard import inspection_views, views

app_name = "dashboard"

urlpatterns = [
    path("login/", auth_views.LoginView.as_view(redirect_authenticated_user=True), name="login"),
    path("logout/", auth_views.LogoutView.as_view(), name="logout"),
    path("", views.home, name="home"),
    path("jobs/", views.job_list, name="jobs"),
    path("jobs/<int:job_id>/", views.job_detail, name="job"),
    path("assets/plotly.min.js", views.plotly_js, name="plotly-js"),
    path("favicon.svg", views.favicon, name="favicon"),
    path("favicon.ico", views.favicon),
    path("rigs/", views.rig_list, name="rigs"),
    path("rigs/<int:rig_id>/", views.rig_detail, name="rig"),
    path("rigs/<int:rig_id>/history/<int:entry_id>/restore/", views.rig_restore, name="rig-restore"),
    path("rigs/<int:rig_id>/captures/", views.rig_captures, name="rig-captures"),
    path("rigs/<int:rig_id>/sensitivity/", views.rig_sensitivity, name="rig-sensitivity"),
    path("captures/", views.capture_list, name="captures"),
    path("captures/<int:capture_id>/", views.capture_detail, name="capture"),
    path("measurements/", views.measurement_list, name="measurements"),
    path("measurements/new/", views.measurement_new, name="measurement-new"),
    path("measurements/<int:measurement_id>/", views.measurement_detail, name="measurement"),
    path("calibrations/", views.calibration_list, name="calibrations"),
    path("calibrations/new/", views.calibration_new, name="calibration-new"),
    path("calibrations/<int:calibration_id>/", views.calibration_detail, name="calibration"),
    path("calibrations/<int:calibration_id>/apply/", views.calibration_apply, name="calibration-apply"),
    path("procam-calibrations/", views.procam_list, name="procam-calibrations"),
    path("procam-calibrations/new/", views.procam_new, name="procam-calibration-new"),
    path("procam-calibrations/<int:calibration_id>/", views.procam_detail, name="procam-calibration"),
    path("procam-calibrations/<int:calibration_id>/apply/", views.procam_apply, name="procam-calibration-apply"),
    path(
        "procam-calibrations/<int:calibration_id>/residuals/<int:index>.svg",
        views.procam_residual_svg,
        name="procam-calibration-residuals",
    ),
    path(
        "procam-calibrations/<int:calibration_id>/coverage/<str:device>.svg",
        views.procam_coverage_svg,
        name="procam-calibration-coverage",
    ),
    path("nominals/", inspection_views.nominal_list, name="nominals"),
    path("inspections/", inspection_views.inspection_list, name="inspections"),
    path("measurements/<int:measurement_id>/inspect/", inspection_views.inspection_new, name="inspection-new"),
    path("inspections/<int:inspection_id>/", inspection_views.inspection_detail, name="inspection"),
    path("inspections/<int:inspection_id>/report/", inspection_views.inspection_report, name="inspection-report"),
    path("rigs/<int:rig_id>/inspection-plan/", inspection_views.rig_inspection_plan, name="rig-inspection-plan"),
    path("characterizations/", views.characterization_list, name="characterizations"),
    path("characterizations/new/", views.characterization_new, name="characterization-new"),
    path("characterizations/<int:characterization_id>/", views.characterization_detail, name="characterization"),
]
