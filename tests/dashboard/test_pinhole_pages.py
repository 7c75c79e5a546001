"""Pinhole rigs on the dashboard: import from a rig file, the rig page, a measurement without a
reference (depths) with its figures, 3D view and sigma map."""

from __future__ import annotations

import json

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.services import upload_capture
from metrology.rigs.models import Rig
from tests.dashboard.helpers import figure_data
from tests.pinhole_stacks import RIG, capture_zip


@pytest.mark.slow
def test_import_a_pinhole_rig_then_measure_depths(client_alice, alice, run_jobs):
    page = client_alice.get("/rigs/")
    assert page.status_code == 200 and "Import a pinhole rig" in page.content.decode()
    rig_file = SimpleUploadedFile("rig.json", RIG.to_json().encode(), "application/json")
    done = client_alice.post("/rigs/", {"action": "pinhole", "pinhole-name": "bench", "pinhole-rig_file": rig_file})
    assert done.status_code == 302, done.content.decode()[:2000]
    rig = Rig.objects.get(owner=alice)
    assert rig.is_pinhole and rig.name == "bench" and rig.to_core() == RIG
    html = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert "pinhole camera and projector" in html and "New calibration" not in html
    # a bad rig file is refused in words
    bad = {**RIG.to_dict(), "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}
    refused = client_alice.post(
        "/rigs/",
        {"action": "pinhole", "pinhole-rig_file": SimpleUploadedFile("bad.json", json.dumps(bad).encode())},
    )
    assert refused.status_code == 400 and "R" in refused.content.decode() and Rig.objects.count() == 1
    data, _ = capture_zip("sphere")
    obj = upload_capture(owner=alice, rig=rig, upload=SimpleUploadedFile("o.zip", data), role="object")
    form = client_alice.get(f"/measurements/new/?rig={rig.pk}").content.decode()
    assert "none: depths (camera Z)" in form
    with run_jobs():
        response = client_alice.post(
            f"/measurements/new/?rig={rig.pk}", {"rig": rig.pk, "reference": "", "object": obj.pk, "sigma": "on"}
        )
    assert response.status_code == 302, response.content.decode()[:3000]
    html = client_alice.get(response["Location"]).content.decode()
    assert "no reference (depths)" in html and "depth (camera Z)" in html
    assert figure_data(html, "surface")["data"][0]["type"] in ("mesh3d", "surface")
    assert figure_data(html, "sigma_map")["data"][0]["type"] == "heatmap"
    assert "points.npy" in html and "mesh.ply" in html


def test_crossed_axes_pages_of_a_pinhole_rig_do_not_fail(client_alice, alice):
    from metrology.rigs.services import create_pinhole_rig

    rig = create_pinhole_rig(owner=alice, data={**RIG.to_dict(), "name": "p"})
    for url in (
        f"/rigs/{rig.pk}/captures/",
        f"/calibrations/new/?rig={rig.pk}",
        f"/characterizations/new/?rig={rig.pk}",
        f"/rigs/{rig.pk}/sensitivity/",
        "/rigs/",
        f"/rigs/{rig.pk}/",
    ):
        response = client_alice.get(url, follow=True)
        assert response.status_code == 200, url


def test_rig_page_restores_a_history_entry(client_alice, client_bob, alice):
    """The history's Restore buttons: a converted rig goes back to its crossed-axes values and the page
    says so; the current entry has no button; a refused restore is shown in words."""
    from metrology.rigs.services import create_rig, set_pinhole_rig_file
    from tests.app.stacks import SMALL_RIG

    rig = create_rig(
        owner=alice, data={**SMALL_RIG, "width_px": RIG.camera.width_px, "height_px": RIG.camera.height_px}
    )
    set_pinhole_rig_file(rig=rig, rig_file=RIG.to_dict(), source="calibration")
    created, converted = rig.history.order_by("id")
    html = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert html.count(">Restore</button>") == 1 and f"/history/{created.pk}/restore/" in html
    assert f"/history/{converted.pk}/restore/" not in html and 'badge done">current' in html

    done = client_alice.post(f"/rigs/{rig.pk}/history/{created.pk}/restore/")
    assert done.status_code == 302 and done["Location"] == f"/rigs/{rig.pk}/#h-hist"
    rig.refresh_from_db()
    assert not rig.is_pinhole and rig.L_mm == SMALL_RIG["L_mm"] and rig.pinhole is None
    page = client_alice.get(f"/rigs/{rig.pk}/")
    html = page.content.decode()
    assert page.status_code == 200
    assert f"restored, the values of {created.created_at:%Y-%m-%d %H:%M:%S}" in html
    assert html.count(">Restore</button>") == 2 and "New calibration" in html  # crossed-axes pages again

    refused = client_alice.post(f"/rigs/{rig.pk}/history/{rig.history.order_by('-id').first().pk}/restore/")
    assert refused.status_code == 400 and "already holds rig" in refused.content.decode()
    assert 'id="restore-error"' in refused.content.decode()
    assert client_bob.get(f"/rigs/{rig.pk}/history/{created.pk}/restore/").status_code == 405
    assert client_bob.post(f"/rigs/{rig.pk}/history/{created.pk}/restore/").status_code == 404
