"""URL routes: the REST API under /api/, its schema and docs, the admin."""

from django.contrib import admin
from django.urls import include, path
from drf_spectacular.views import SpectacularAPIView, SpectacularSwaggerSplitView

from metrology.acquisition import urls as acquisition_urls
from metrology.calibrations import api as calibrations
from metrology.calibrations import procam_api as procam
from metrology.captures import api as captures
from metrology.characterizations import api as characterizations
from metrology.inspections import api as inspections
from metrology.jobs import api as jobs
from metrology.measurements import api as measurements
from metrology.measurements.models import RESULT_FILES
from metrology.rigs import api as rigs

api_patterns = [
    path("rigs/", rigs.RigListCreateApi.as_view(), name="rigs"),
    path("rigs/<int:rig_id>/", rigs.RigDetailApi.as_view(), name="rig"),
    path("rigs/<int:rig_id>/codec/", rigs.RigCodecApi.as_view(), name="rig-codec"),
    path(
        "rigs/<int:rig_id>/history/<int:entry_id>/restore/",
        rigs.RigHistoryRestoreApi.as_view(),
        name="rig-history-restore",
    ),
    path("rigs/<int:rig_id>/captures/", captures.RigCapturesApi.as_view(), name="rig-captures"),
    path("rigs/<int:rig_id>/captures/simulate/", captures.RigCaptureSimulateApi.as_view(), name="rig-simulate"),
    path("rigs/<int:rig_id>/sessions/", captures.RigSessionsApi.as_view(), name="rig-sessions"),
    path("captures/<int:capture_id>/", captures.CaptureDetailApi.as_view(), name="capture"),
    path("captures/<int:capture_id>/stack.zip", captures.CaptureFileApi.as_view(), name="capture-stack"),
    path("jobs/", jobs.JobListApi.as_view(), name="jobs"),
    path("jobs/<int:job_id>/", jobs.JobDetailApi.as_view(), name="job"),
    path("measurements/", measurements.MeasurementListCreateApi.as_view(), name="measurements"),
    path("measurements/<int:measurement_id>/", measurements.MeasurementDetailApi.as_view(), name="measurement"),
    path(
        "measurements/<int:measurement_id>/acceptance/",
        measurements.MeasurementAcceptanceApi.as_view(),
        name="measurement-acceptance",
    ),
    *[
        path(
            f"measurements/<int:measurement_id>/{name}",
            measurements.file_view(name).as_view(),
            name=f"measurement-{name}",
        )
        for name in RESULT_FILES
    ],
    path("calibrations/", calibrations.CalibrationListCreateApi.as_view(), name="calibrations"),
    path("calibrations/<int:calibration_id>/", calibrations.CalibrationDetailApi.as_view(), name="calibration"),
    path(
        "calibrations/<int:calibration_id>/apply/", calibrations.CalibrationApplyApi.as_view(), name="calibration-apply"
    ),
    path("procam-calibrations/", procam.ProcamCalibrationListCreateApi.as_view(), name="procam-calibrations"),
    path(
        "procam-calibrations/<int:calibration_id>/",
        procam.ProcamCalibrationDetailApi.as_view(),
        name="procam-calibration",
    ),
    path(
        "procam-calibrations/<int:calibration_id>/apply/",
        procam.ProcamCalibrationApplyApi.as_view(),
        name="procam-calibration-apply",
    ),
    path(
        "procam-calibrations/<int:calibration_id>/report.json",
        procam.ProcamCalibrationReportApi.as_view(),
        name="procam-calibration-report",
    ),
    path(
        "procam-calibrations/<int:calibration_id>/rig.json",
        procam.ProcamCalibrationRigFileApi.as_view(),
        name="procam-calibration-rig",
    ),
    path("characterizations/", characterizations.CharacterizationListCreateApi.as_view(), name="characterizations"),
    path(
        "characterizations/<int:characterization_id>/",
        characterizations.CharacterizationDetailApi.as_view(),
        name="characterization",
    ),
    *[
        path(
            f"characterizations/<int:characterization_id>/{table}.csv",
            characterizations.csv_view(table).as_view(),
            name=f"characterization-{table}-csv",
        )
        for table in ("positions", "test_points")
    ],
    path("nominals/", inspections.NominalListCreateApi.as_view(), name="nominals"),
    path("nominals/<int:nominal_id>/", inspections.NominalDetailApi.as_view(), name="nominal"),
    path("nominals/<int:nominal_id>/file/", inspections.NominalFileApi.as_view(), name="nominal-file"),
    path("inspections/", inspections.InspectionListCreateApi.as_view(), name="inspections"),
    path("inspections/<int:inspection_id>/", inspections.InspectionDetailApi.as_view(), name="inspection"),
    path(
        "inspections/<int:inspection_id>/deviations.npy",
        inspections.InspectionDeviationsApi.as_view(),
        name="inspection-deviations",
    ),
    path(
        "inspections/<int:inspection_id>/deviations.ply",
        inspections.InspectionDeviationsPlyApi.as_view(),
        name="inspection-deviations-ply",
    ),
    path("rigs/<int:rig_id>/inspection-plan/", inspections.RigInspectionPlanApi.as_view(), name="rig-inspection-plan"),
    *acquisition_urls.api_patterns,
    path("schema/", SpectacularAPIView.as_view(), name="schema"),
    path("docs/", SpectacularSwaggerSplitView.as_view(url_name="schema"), name="docs"),  # no inline script
]

urlpatterns = [
    path("api/", include(api_patterns)),
    path("admin/", admin.site.urls),
    path("reports/", include("metrology.reports.urls")),
    path("", include("metrology.acquisition.urls")),
    path("", include("metrology.dashboard.urls")),
]

handler400 = "metrology.api_errors.bad_request"
handler404 = "metrology.api_errors.not_found"
handler500 = "metrology.api_errors.server_error"
