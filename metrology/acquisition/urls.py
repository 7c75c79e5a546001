"""Routes of acquisition: API routes (mounted under /api/) and page routes (at the site root)."""

from django.urls import path

from metrology.acquisition import api, views

api_patterns = [
    path("rigs/<int:rig_id>/captures/acquire/", api.RigAcquireApi.as_view(), name="api-rig-acquire"),
    path("rigs/<int:rig_id>/agent/", api.RigAgentApi.as_view(), name="api-rig-agent"),
    path("rigs/<int:rig_id>/agent/register/", api.RigAgentRegisterApi.as_view(), name="api-rig-agent-register"),
    path("rigs/<int:rig_id>/agent/heartbeat/", api.RigAgentHeartbeatApi.as_view(), name="api-rig-agent-heartbeat"),
    path("rigs/<int:rig_id>/agent/disconnect/", api.RigAgentDisconnectApi.as_view(), name="api-rig-agent-disconnect"),
    path("rigs/<int:rig_id>/agent/take/", api.RigAgentTakeApi.as_view(), name="api-rig-agent-take"),
    path("rigs/<int:rig_id>/projector/", api.rig_projector, name="api-rig-projector"),
    path("rigs/<int:rig_id>/projector/shown/", api.RigProjectorShownApi.as_view(), name="api-rig-projector-shown"),
    path("acquisitions/<int:acquisition_id>/", api.AcquisitionDetailApi.as_view(), name="api-acquisition"),
    path(
        "acquisitions/<int:acquisition_id>/progress/",
        api.AcquisitionProgressApi.as_view(),
        name="api-acquisition-progress",
    ),
    path("acquisitions/<int:acquisition_id>/fail/", api.AcquisitionFailApi.as_view(), name="api-acquisition-fail"),
    path(
        "acquisitions/<int:acquisition_id>/upload/", api.AcquisitionUploadApi.as_view(), name="api-acquisition-upload"
    ),
]

app_name = "acquisition"

urlpatterns = [
    path("rigs/<int:rig_id>/acquire/", views.acquire_page, name="acquire"),
    path("acquisitions/<int:acquisition_id>/", views.acquisition_page, name="acquisition"),
    path(
        "acquisitions/<int:acquisition_id>/frames/<int:frame>.png",
        views.acquisition_thumbnail,
        name="acquisition-thumbnail",
    ),
    path("rigs/<int:rig_id>/projector/", views.projector_page, name="projector"),
    path(
        "rigs/<int:rig_id>/projector/acquisitions/<int:acquisition_id>/frames/<int:frame>.png",
        views.projector_frame,
        name="projector-frame",
    ),
]
