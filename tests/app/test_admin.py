"""The admin lists every model of the experiment database."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(
    "model",
    [
        "rigs/rig",
        "captures/capture",
        "captures/capturesession",
        "jobs/job",
        "measurements/measurement",
        "calibrations/calibration",
        "calibrations/procamcalibration",
        "characterizations/characterization",
    ],
)
def test_admin_changelists_render(admin_client, rig, model):
    response = admin_client.get(f"/admin/{model}/")
    assert response.status_code == 200
    response = admin_client.get(f"/admin/rigs/rig/{rig['id']}/change/")
    assert response.status_code == 200
