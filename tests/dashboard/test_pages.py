"""Pages with the Django test client: login, owner isolation, forms and their errors, results."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from metrology.characterizations.services import request_characterization
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.services import request_measurement
from metrology.rigs.models import Rig
from tests.conftest import PASSWORD
from tests.dashboard.conftest import upload
from tests.dashboard.helpers import capture_listing_pages

PAGES = [
    "/",
    "/rigs/",
    "/captures/",
    "/measurements/",
    "/measurements/new/",
    "/calibrations/",
    "/calibrations/new/",
    "/characterizations/",
    "/characterizations/new/",
]


@pytest.mark.django_db
@pytest.mark.parametrize("url", [*PAGES, "/rigs/1/", "/measurements/1/", "/jobs/1/", "/assets/plotly.min.js"])
def test_pages_need_a_login(client, url):
    response = client.get(url)
    assert response.status_code == 302
    assert response["Location"].startswith(f"/login/?next={url}")


@pytest.mark.parametrize("url", PAGES)
def test_empty_pages_say_what_to_do_next(client_alice, url):
    response = client_alice.get(url)
    assert response.status_code == 200
    text = response.content.decode()
    assert "rig" in text.lower()
    assert 'class="empty"' in text


def test_login_with_password_then_logout(client, alice):
    page = client.get("/login/")
    assert page.status_code == 200 and b"Log in" in page.content
    bad = client.post("/login/", {"username": "alice", "password": "wrong"})
    assert b"did not match" in bad.content
    good = client.post("/login/", {"username": "alice", "password": PASSWORD, "next": "/rigs/"})
    assert good.status_code == 302 and good["Location"] == "/rigs/"
    assert client.get("/rigs/").status_code == 200
    assert client.post("/logout/").status_code == 302
    assert client.get("/rigs/").status_code == 302


def test_create_rig_from_the_form(client_alice, alice):
    response = client_alice.post(
        "/rigs/",
        {
            "name": "new",
            "L_mm": 1022,
            "d_mm": 352,
            "alpha_rad": 0.332,
            "fw_mm": 500,
            "nlp": 128,
            "width_px": 320,
            "height_px": 240,
        },
    )
    rig = Rig.objects.get(owner=alice, name="new")
    assert response.status_code == 302 and response["Location"] == f"/rigs/{rig.pk}/"
    page = client_alice.get(response["Location"]).content.decode()
    assert "<dt>L</dt><dd>1022 mm</dd>" in page and "created" in page


def test_rig_form_shows_the_services_error_in_words(client_alice, alice):
    response = client_alice.post(
        "/rigs/",
        {
            "name": "bad",
            "L_mm": 1022,
            "d_mm": 352,
            "alpha_rad": 2.0,
            "fw_mm": 500,
            "nlp": 128,
            "width_px": 320,
            "height_px": 240,
        },
    )
    assert response.status_code == 400
    assert b"alpha" in response.content and b'class="alert"' in response.content
    assert not Rig.objects.filter(owner=alice).exists()
    missing = client_alice.post("/rigs/", {"name": "x"})
    assert missing.status_code == 400 and b"This field is required" in missing.content


def test_another_users_objects_are_not_found(client_bob, rig, captures, run_jobs, alice):
    reference, obj = captures
    with run_jobs():
        measurement = request_measurement(owner=alice, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    for url in (
        f"/rigs/{rig.pk}/",
        f"/rigs/{rig.pk}/captures/",
        f"/rigs/{rig.pk}/sensitivity/",
        f"/measurements/{measurement.pk}/",
        f"/measurements/new/?rig={rig.pk}",
        f"/jobs/{measurement.job_id}/",
        f"/api/measurements/{measurement.pk}/mesh.ply",
    ):
        response = client_bob.get(url)
        assert response.status_code == 404, url
    assert b"Not found" in client_bob.get(f"/rigs/{rig.pk}/").content  # an HTML page, not JSON
    assert client_bob.get("/measurements/").content.count(b"Measurement ") == 0


def test_simulate_capture_form_runs_the_job_and_lists_the_capture(client_alice, rig, run_jobs):
    with run_jobs():
        response = client_alice.post(
            f"/rigs/{rig.pk}/captures/",
            {"action": "simulate", "simulate-scene": "reference", "simulate-noise": "none", "simulate-seed": 1},
        )
    assert response.status_code == 302 and response["Location"].startswith("/jobs/")
    job = Job.objects.get(pk=int(response["Location"].split("/")[2]))
    assert job.status == "done", job.error
    page = client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode()
    assert "Reference plane" in page and "stored" in page


def test_simulate_form_shows_errors_in_words(client_alice, rig):
    response = client_alice.post(
        f"/rigs/{rig.pk}/captures/",
        {"action": "simulate", "simulate-scene": "block", "simulate-z_mm": -5, "simulate-noise": "none"},
    )
    assert response.status_code == 400
    assert b'class="alert"' in response.content and b"top_mm must be positive" in response.content


def test_upload_form_refuses_a_bad_zip_in_words(client_alice, rig):
    from django.core.files.uploadedfile import SimpleUploadedFile

    response = client_alice.post(
        f"/rigs/{rig.pk}/captures/",
        {"action": "upload", "upload-role": "object", "upload-file": SimpleUploadedFile("x.zip", b"not a zip")},
    )
    assert response.status_code == 400
    assert b"capture stack refused" in response.content


def test_upload_form_stores_a_stack(client_alice, rig, alice):
    from django.core.files.uploadedfile import SimpleUploadedFile

    from tests.app.stacks import SMALL_RIG, plane_zip

    response = client_alice.post(
        f"/rigs/{rig.pk}/captures/",
        {
            "action": "upload",
            "upload-role": "reference",
            "upload-file": SimpleUploadedFile("r.zip", plane_zip(SMALL_RIG)),
        },
    )
    assert response.status_code == 302
    assert rig.captures.filter(role="reference").exclude(file="").count() == 1


def test_uploaded_captures_are_listed_on_every_capture_page(client_alice, rig, alice):
    """Uploads carry no scene parameters: every page that lists captures must still render them."""
    from django.core.files.uploadedfile import SimpleUploadedFile

    from metrology.captures.models import Capture
    from metrology.captures.services import create_session
    from tests.app.stacks import SMALL_RIG, plane_zip

    for name, role, z_mm in (("plane-r.zip", "reference", 0.0), ("block-o.zip", "object", 10.0)):
        data = {
            "action": "upload",
            "upload-role": role,
            "upload-file": SimpleUploadedFile(name, plane_zip(SMALL_RIG, z_mm)),
        }
        response = client_alice.post(f"/rigs/{rig.pk}/captures/", data, follow=True)
        assert response.status_code == 200 and name.encode() in response.content  # the page it redirects to
    reference = Capture.objects.get(rig=rig, role="reference")
    obj = Capture.objects.get(rig=rig, role="object")
    assert reference.parameters == {} and obj.parameters == {}
    session = create_session(owner=alice, rig=rig, name="stage")  # so that the characterization form shows
    for z in (0.0, 4.0):
        upload(alice, rig, z, "stage", z_in_mm=z, session_id=session.pk)
    for url, expected in capture_listing_pages(rig.pk, reference.pk, obj.pk).items():
        page = client_alice.get(url)
        assert page.status_code == 200, url
        text = page.content.decode()
        for marker in expected:
            assert marker in text, (url, marker)


def test_measurement_form_runs_a_measurement_and_shows_its_figures(client_alice, rig, captures, run_jobs):
    reference, obj = captures
    form = client_alice.get(f"/measurements/new/?rig={rig.pk}")
    assert form.status_code == 200 and f'value="{reference.pk}"'.encode() in form.content
    with run_jobs():
        response = client_alice.post("/measurements/new/", {"rig": rig.pk, "reference": reference.pk, "object": obj.pk})
    assert response.status_code == 302
    measurement = Measurement.objects.get(rig=rig)
    assert response["Location"] == f"/measurements/{measurement.pk}/"
    page = client_alice.get(response["Location"] + "?row=60").content.decode()
    for marker in ('id="fig-height_map"', 'id="fig-profile"', 'id="fig-gray_vs_gcps"', 'id="fig-surface"'):
        assert marker in page
    assert "Profile along row 60" in page
    for name in ("height.npy", "height.tiff", "mesh.ply", "mesh.stl", "mesh.obj"):
        assert f"/api/measurements/{measurement.pk}/{name}" in page
    with run_jobs():  # the mesh is built by a job: 202 naming it, then the file
        pending = client_alice.get(f"/api/measurements/{measurement.pk}/mesh.ply")  # session auth
    assert pending.status_code == 202 and pending["Location"] == f"/api/jobs/{pending.json()['job']}/"
    download = client_alice.get(f"/api/measurements/{measurement.pk}/mesh.ply")
    assert download.status_code == 200
    assert b"".join(download.streaming_content).startswith(b"ply")


def test_measurement_form_errors_in_words(client_alice, rig, captures):
    reference, _obj = captures
    response = client_alice.post("/measurements/new/", {"rig": rig.pk, "reference": reference.pk, "object": ""})
    assert response.status_code == 400 and b"This field is required" in response.content


def test_a_failed_job_shows_its_reason(client_alice, rig, captures, run_jobs, alice, monkeypatch):
    import metrology.core.measure as measure

    def broken(*_args, **_kwargs):
        raise ValueError("the object stack decodes to nothing")

    monkeypatch.setattr(measure, "measure", broken)
    reference, obj = captures
    with run_jobs():
        measurement = request_measurement(owner=alice, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    page = client_alice.get(f"/measurements/{measurement.pk}/").content.decode()
    assert "The job failed: the object stack decodes to nothing" in page


def test_running_job_shows_a_progress_bar_polling_the_job(client_alice, rig, captures, alice, monkeypatch):
    import metrology.jobs.services as job_services

    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: None)
    reference, obj = captures
    measurement = request_measurement(owner=alice, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    page = client_alice.get(f"/measurements/{measurement.pk}/").content.decode()
    assert 'role="progressbar"' in page and f'data-url="/api/jobs/{measurement.job_id}/"' in page
    job_page = client_alice.get(f"/jobs/{measurement.job_id}/").content.decode()
    assert f'data-next="/measurements/{measurement.pk}/"' in job_page
    api = client_alice.get(f"/api/jobs/{measurement.job_id}/")  # what the bar polls, with the session cookie
    assert api.status_code == 200 and api.json()["status"] == "queued"


def test_characterization_from_a_stage_session(client_alice, rig, alice, run_jobs):
    from metrology.captures.services import create_session

    reference = upload(alice, rig, 0.0, "reference")
    session = create_session(owner=alice, rig=rig, name="stage")
    for z in (0.0, 4.0, 8.0):
        for repeat in range(2):
            upload(alice, rig, z, "stage", z_in_mm=z, repeat=repeat, session_id=session.pk)
    form = client_alice.get(f"/characterizations/new/?rig={rig.pk}&session={session.pk}")
    assert form.status_code == 200 and b"6 stage captures" in form.content
    with run_jobs():
        response = client_alice.post(
            "/characterizations/new/",
            {"rig": rig.pk, "reference": reference.pk, "session": session.pk, "n_points": 9, "rows": 1},
        )
    assert response.status_code == 302, response.content.decode()[:2000]
    page = client_alice.get(response["Location"]).content.decode()
    for key in ("in_out", "error_vs_z", "slope_vs_x", "intercept_vs_x", "sigma_vs_x"):
        assert f'id="fig-{key}"' in page
    assert "Fig. 12" in page and "Fig. 13" in page and "% of full scale" in page


def test_result_pages_show_no_float_noise(client_alice, rig, alice, run_jobs):
    """A calibrated rig (L = 1021.98533...) is shown rounded on the pages that list its values."""
    from metrology.captures.services import create_session
    from metrology.rigs.services import update_rig_parameters

    update_rig_parameters(rig=rig, changes={"L_mm": 1021.9853333333333, "alpha_rad": 0.33212345678901}, source="manual")
    rig.refresh_from_db()
    reference = upload(alice, rig, 0.0, "reference")
    session = create_session(owner=alice, rig=rig, name="stage")
    for z in (0.0, 0.1 + 0.2, 8.0):  # 0.30000000000000004 mm
        upload(alice, rig, z, "stage", z_in_mm=z, session_id=session.pk)
    with run_jobs():
        characterization = request_characterization(
            owner=alice, rig=rig, reference_id=reference.pk, session_id=session.pk, options={"n_points": 5}
        )
    characterization.job.refresh_from_db()
    assert characterization.job.status == "done", characterization.job.error
    for url in (f"/characterizations/{characterization.pk}/", f"/rigs/{rig.pk}/", f"/rigs/{rig.pk}/captures/"):
        text = visible_text(client_alice.get(url).content.decode())
        assert not re.search(r"\d\.\d{7,}", text), (url, re.findall(r"\S*\d\.\d{7,}\S*", text))
    page = visible_text(client_alice.get(f"/characterizations/{characterization.pk}/").content.decode())
    assert "L 1021.9853 mm" in page, page[page.find("Rig values") :][:300]
    rig_page = visible_text(client_alice.get(f"/rigs/{rig.pk}/").content.decode())
    assert "Z_in 0.3 mm" in rig_page, rig_page[rig_page.find("stage") :][:300]


def test_characterization_form_error_in_words(client_alice, rig, alice):
    from metrology.captures.services import create_session

    reference = upload(alice, rig, 0.0, "reference")
    session = create_session(owner=alice, rig=rig, name="one position")
    upload(alice, rig, 0.0, "stage", z_in_mm=0.0, session_id=session.pk)
    response = client_alice.post(
        "/characterizations/new/",
        {"rig": rig.pk, "reference": reference.pk, "session": session.pk, "n_points": 9, "rows": 1},
    )
    assert response.status_code == 400
    assert b"two or more distinct z_in_mm positions" in response.content


def calibrate_40mm_master_from_the_paper_start(client_alice, rig, alice, run_jobs):
    """Upload a reference and a 40 mm master, and run an lsq calibration through the form from the
    paper's rough start (L0 = 1080 mm, alpha0 = 0.4871 rad); the form's response."""
    z = np.zeros((rig.height_px, rig.width_px))
    z[25:95, 30:130] = 40.0
    reference = upload(alice, rig, 0.0, "reference")
    master = upload(alice, rig, z, "master")
    with run_jobs():
        response = client_alice.post(
            "/calibrations/new/",
            {
                "rig": rig.pk,
                "reference": reference.pk,
                "master": master.pk,
                "master_height_mm": 40,
                "method": "lsq",
                "initial_L_mm": 1080,
                "initial_alpha_rad": 0.4871,
            },
        )
    return response


def test_calibration_page_and_apply(client_alice, rig, alice, run_jobs):
    response = calibrate_40mm_master_from_the_paper_start(client_alice, rig, alice, run_jobs)
    assert response.status_code == 302
    page = client_alice.get(response["Location"]).content.decode()
    for key in ("calibration_parameters", "calibration_profiles", "calibration_residual"):
        assert f'id="fig-{key}"' in page
    applied = client_alice.post(response["Location"] + "apply/")
    assert applied.status_code == 302 and applied["Location"] == f"/rigs/{rig.pk}/"
    rig.refresh_from_db()
    assert abs(rig.parameters["L_mm"] - 1022.0) < 1.0
    assert "calibration" in client_alice.get(f"/rigs/{rig.pk}/").content.decode()


def visible_text(html: str) -> str:
    """The text a reader sees: scripts, styles and tags removed."""
    html = re.sub(r"<(script|style)\b.*?</\1>", " ", html, flags=re.S)
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))


def figure_data(html: str, name: str) -> dict:
    """The plotly figure JSON embedded for ``fig-<name>``."""
    found = re.search(rf'<script type="application/json" id="fig-{name}-data">(.*?)</script>', html, flags=re.S)
    assert found, name
    return json.loads(found.group(1))


def test_calibration_page_shows_start_result_and_iterations_in_plain_words(client_alice, rig, alice, run_jobs):
    """Paper's rough start L0 = 1080 mm on a rig stored at 1022 mm: the page shows start -> result."""
    response = calibrate_40mm_master_from_the_paper_start(client_alice, rig, alice, run_jobs)
    assert response.status_code == 302
    html = client_alice.get(response["Location"]).content.decode()
    text = visible_text(html)
    # the true starting values, then the result (true values 1022 mm, 0.332 rad: within 1 mm, 1 mrad)
    start_to_result = re.search(r"L 1080\.000 mm → (\d+\.\d{3}) mm ± [\d.]+ µm", text)
    assert start_to_result, text
    assert abs(float(start_to_result.group(1)) - 1022.0) < 1.0
    alpha = re.search(r"alpha 0\.48710 rad → (\d\.\d{5}) rad ± [\d.]+ µrad", text)
    assert alpha and abs(float(alpha.group(1)) - 0.332) < 1e-3, text
    assert "the rig's stored value was 1022.000 mm" in text
    # the count in words equals the points drawn after the start (iteration 0)
    count = re.search(r"after (\d+) iterations", text)
    assert count, text
    trace = figure_data(html, "calibration_parameters")["data"][0]
    assert trace["x"][0] == 0 and len(trace["x"]) == int(count.group(1)) + 1
    # plain words, no optimizer message, no long numbers, one spelling of micrometres
    assert "`" not in text and not re.search(r"\b[fxg]tol\b", text) and "termination condition" not in text
    assert not re.search(r"\d\.\d{7,}", text), re.findall(r"\S*\d\.\d{7,}\S*", text)
    assert "µm" in text and not re.search(r"\bum\b", text)
    assert "(µm)" in json.dumps(figure_data(html, "calibration_residual"), ensure_ascii=False)


def test_sensitivity_page_draws_figs_4_to_6(client_alice, rig):
    page = client_alice.get(f"/rigs/{rig.pk}/sensitivity/?z_mm=30").content.decode()
    for key in ("L", "d", "alpha"):
        assert f'id="fig-sensitivity_{key}"' in page
    assert "Fig. 4" in page and "Fig. 6" in page
    bad = client_alice.get(f"/rigs/{rig.pk}/sensitivity/?z_mm=abc").content.decode()
    assert "Height not usable" in bad


def test_plotly_is_served_locally(client_alice):
    response = client_alice.get("/assets/plotly.min.js")
    assert response.status_code == 200 and len(response.content) > 1_000_000
    page = client_alice.get("/rigs/").content.decode()
    assert "cdn" not in page.lower()


def test_characterization_of_another_user_is_404(client_bob, rig, alice, run_jobs):
    from metrology.captures.services import create_session

    reference = upload(alice, rig, 0.0, "reference")
    session = create_session(owner=alice, rig=rig)
    for z in (0.0, 4.0):
        upload(alice, rig, z, "stage", z_in_mm=z, session_id=session.pk)
    with run_jobs():
        characterization = request_characterization(
            owner=alice, rig=rig, reference_id=reference.pk, session_id=session.pk, options={"n_points": 5}
        )
    assert client_bob.get(f"/characterizations/{characterization.pk}/").status_code == 404
    assert client_bob.get(f"/api/jobs/{characterization.job_id}/").status_code == 404


@pytest.mark.django_db
def test_every_page_names_a_favicon_that_is_served_without_login(client, client_alice):
    page = client_alice.get("/rigs/").content.decode()
    assert '<link rel="icon" href="/favicon.svg" type="image/svg+xml">' in page
    assert '<link rel="icon"' in client.get("/login/").content.decode()
    for url in ("/favicon.svg", "/favicon.ico"):  # browsers ask for /favicon.ico by themselves
        response = client.get(url)
        assert response.status_code == 200 and response["Content-Type"] == "image/svg+xml"
        assert response.content.startswith(b"<svg") and b"</svg>" in response.content
