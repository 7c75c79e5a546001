"""Pinhole rigs on the dashboard: import from a rig file, the rig page, a measurement without a
reference (depths) with its figures, 3D view and sigma map."""

from __future__ import annotations

import json
from html import unescape

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.services import upload_capture
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.rigs.models import Rig
from tests.dashboard.helpers import figure_data
from tests.pinhole_stacks import RIG, capture_zip


@pytest.mark.slow
def test_import_a_pinhole_rig_then_measure_depths(client_alice, alice, run_jobs):
    page = client_alice.get("/rigs/")
    assert page.status_code == 200 and "Import a rig file" in page.content.decode()
    rig_file = SimpleUploadedFile("rig.json", RIG.to_json().encode(), "application/json")
    done = client_alice.post("/rigs/", {"action": "rig_file", "file-name": "bench", "file-rig_file": rig_file})
    assert done.status_code == 302, done.content.decode()[:2000]
    rig = Rig.objects.get(owner=alice)
    assert rig.model == "pinhole" and rig.name == "bench" and rig.to_core() == RIG
    html = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert "pinhole camera and projector" in html and "New calibration" not in html
    # a bad rig file is refused in words
    bad = {**RIG.to_dict(), "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}
    refused = client_alice.post(
        "/rigs/",
        {"action": "rig_file", "file-rig_file": SimpleUploadedFile("bad.json", json.dumps(bad).encode())},
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
    from metrology.rigs.services import create_rig

    rig = create_rig(owner=alice, data={**RIG.to_dict(), "name": "p"})
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
    from metrology.rigs.services import create_rig, set_rig_model
    from tests.app.stacks import SMALL_RIG

    crossed = {**SMALL_RIG, "width_px": RIG.camera.width_px, "height_px": RIG.camera.height_px}
    rig = create_rig(owner=alice, data=crossed)
    set_rig_model(rig=rig, model=RIG, source="calibration")
    created, converted = rig.history.order_by("id")
    html = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert html.count(">Restore</button>") == 1 and f"/history/{created.pk}/restore/" in html
    assert f"/history/{converted.pk}/restore/" not in html and 'badge done">current' in html

    done = client_alice.post(f"/rigs/{rig.pk}/history/{created.pk}/restore/")
    assert done.status_code == 302 and done["Location"] == f"/rigs/{rig.pk}/#h-hist"
    rig.refresh_from_db()
    assert rig.model == "crossed_axes" and rig.parameters["L_mm"] == SMALL_RIG["L_mm"]
    assert rig.to_core() == CoreRig.from_dict(crossed)
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


def test_a_rig_whose_default_codec_it_cannot_measure_is_offered_one_it_can(client_alice, alice):
    """A pinhole rig (640 x 400 projector) left with the 1024 x 768 gcps-v1: the captures page says why
    it cannot simulate and offers the paper's patterns at the rig's projector size, which one click
    sets; a new rig gets that codec from the start."""
    from metrology.rigs.services import create_rig

    assert create_rig(owner=alice, data={**RIG.to_dict(), "name": "new"}).codec == "gcps-v1:640x400"
    rig = create_rig(owner=alice, data={**RIG.to_dict(), "name": "old", "codec": "gcps-v1"})
    html = unescape(client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode())
    assert "the codec's projector is 1024x768 but the rig's projector is 640x400" in html
    assert "Use gcps-v1:640x400 as the default codec" in html and 'name="simulate-scene"' not in html
    rig_page = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert "Upload</a> an object (and a reference plane, for heights above it" in rig_page
    done = client_alice.post(f"/rigs/{rig.pk}/", {"codec": "gcps-v1:640x400", "next": "captures"})
    assert done.status_code == 302 and done["Location"] == f"/rigs/{rig.pk}/captures/"
    rig.refresh_from_db()
    assert rig.codec == "gcps-v1:640x400"
    html = client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode()
    assert 'name="simulate-scene"' in html and "simulation-refused" not in html


def test_the_rig_page_imports_a_calibration_file_into_the_rig_or_says_why_not(client_alice, alice, rig, tmp_path):
    """A FileStorage file imported on a crossed-axes rig's page makes it a pinhole rig (history entry
    ``imported``); a file without the needed nodes is refused with the import's message, and the rig
    keeps its values."""
    from metrology.rigs.models import RigParameters
    from tests.pinhole_stacks import PROJ_H, PROJ_W, write_filestorage_yaml

    bad = client_alice.post(
        f"/rigs/{rig.pk}/",
        {
            "action": "calibration",
            "import-calibration_file": SimpleUploadedFile("empty.yml", b"%YAML:1.0\n---\nfoo: 1\n"),
            "import-projector_width": PROJ_W,
            "import-projector_height": PROJ_H,
            "import-camera_width_px": 160,
            "import-camera_height_px": 120,
        },
    )
    assert bad.status_code == 400 and "camera_K" in unescape(bad.content.decode()), unescape(bad.content.decode())
    rig.refresh_from_db()
    assert rig.model == "crossed_axes" and rig.history.count() == 1
    path = tmp_path / "calibration.yml"
    write_filestorage_yaml(path)
    done = client_alice.post(
        f"/rigs/{rig.pk}/",
        {
            "action": "calibration",
            "import-calibration_file": SimpleUploadedFile("calibration.yml", path.read_bytes()),
            "import-projector_width": PROJ_W,
            "import-projector_height": PROJ_H,
        },
    )
    assert done.status_code == 302 and done["Location"] == f"/rigs/{rig.pk}/"
    rig.refresh_from_db()
    assert rig.to_core() == RIG and rig.history.latest("id").source == RigParameters.Source.IMPORTED
    page = unescape(client_alice.get(done["Location"]).content.decode())
    assert "camera_K from cam_int" in page and "imported" in page


def test_the_rigs_page_imports_a_file_that_numbers_its_devices_and_names_its_nodes(client_alice, alice, tmp_path):
    """A FileStorage file with the camera ``M1 D1``, the projector ``M4 D4``, its pose ``Rlp Tlp`` and
    the image size ``S`` (width, height) makes the same rig as the stereo script's layout; the
    message on the new rig's page names every node it read and where the camera size came from."""
    from tests.pinhole_stacks import NUMBERED_DEVICE_NODES, PROJ_H, PROJ_W, write_filestorage_yaml

    path = tmp_path / "calibration.yml"
    write_filestorage_yaml(path, NUMBERED_DEVICE_NODES)
    done = client_alice.post(
        "/rigs/",
        {
            "action": "calibration",
            "import-name": "numbered",
            "import-calibration_file": SimpleUploadedFile("calibration.yml", path.read_bytes()),
            "import-projector_width": PROJ_W,
            "import-projector_height": PROJ_H,
        },
    )
    assert done.status_code == 302, unescape(done.content.decode())[:3000]
    rig = Rig.objects.get(owner=alice)
    assert rig.to_core() == RIG
    page = unescape(client_alice.get(done["Location"]).content.decode())
    for key, node in NUMBERED_DEVICE_NODES.items():
        if key != "size":
            assert f"{key} from {node}" in page, (key, node)
    assert f"camera {RIG.camera.width_px} x {RIG.camera.height_px} px" in page and "#S (width, height)" in page
