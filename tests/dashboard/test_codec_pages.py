"""Codec pages: a rig's default codec on the rig page, a capture's decoding on the capture page."""

from __future__ import annotations

import json
import re

from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.services import upload_capture
from metrology.rigs.models import Rig
from tests.app.codec_stacks import CODEC, codec_images, codec_zip
from tests.dashboard.helpers import figure_data


def test_rig_page_shows_and_sets_the_default_codec(client_alice, rig):
    page = client_alice.get(f"/rigs/{rig.pk}/")
    assert page.status_code == 200
    html = page.content.decode()
    assert "Default codec" in html and "gcps-v1" in html
    done = client_alice.post(f"/rigs/{rig.pk}/", {"codec": json.dumps(CODEC)})
    assert done.status_code == 302
    assert Rig.objects.get(pk=rig.pk).codec["axes"]["u"]["phase"][0]["period"] == 32.0
    shown = client_alice.get(f"/rigs/{rig.pk}/").content.decode()
    assert "gcps-codec/1: 24 frames, axes u, projector 1024x768" in shown
    refused = client_alice.post(f"/rigs/{rig.pk}/", {"codec": json.dumps({**CODEC, "framez": 1})})
    assert refused.status_code == 400 and "framez" in refused.content.decode()
    bad_json = client_alice.post(f"/rigs/{rig.pk}/", {"codec": "{not json"})
    assert bad_json.status_code == 400 and "not valid JSON" in bad_json.content.decode()
    assert Rig.objects.get(pk=rig.pk).codec["codec"] == "gcps-codec/1"  # unchanged by the refusals


def test_capture_page_shows_the_decoded_maps_modulation_and_reasons(client_alice, rig, alice):
    images = codec_images(0.0)
    images[:, :, :20] = 0  # a dark band: refused as too dark
    capture = upload_capture(
        owner=alice,
        rig=rig,
        upload=SimpleUploadedFile("ref.zip", codec_zip(images), "application/zip"),
        role="reference",
    )
    page = client_alice.get(f"/captures/{capture.pk}/")
    assert page.status_code == 200
    html = page.content.decode()
    assert "gcps-codec/1: 24 frames" in html and "too dark: 2400" in html
    u = figure_data(html, "coordinate_u")
    assert u["data"][0]["type"] == "heatmap"
    modulation = figure_data(html, "modulation_u")
    assert modulation["data"][0]["type"] == "heatmap"
    reasons = figure_data(html, "reason_u")
    ticks = reasons["data"][0]["colorbar"]["ticktext"]
    assert any(t.startswith("too dark (2400 px)") for t in ticks) and any(t.startswith("valid") for t in ticks)
    assert "coordinate_v" not in html  # the codec codes u only
    # the capture list links to the page
    assert f'href="/captures/{capture.pk}/"' in client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode()


def test_capture_page_of_a_gcps_v1_capture(client_alice, rig, captures):
    reference, _ = captures
    html = client_alice.get(f"/captures/{reference.pk}/").content.decode()
    assert "gcps-v1" in html
    assert figure_data(html, "coordinate_u")["data"][0]["type"] == "heatmap"
    decoded = re.search(r'<td>u</td><td class="num">[\d.]+ % \(([\d,]+) of [\d,]+ px\)</td>', html)
    assert decoded and int(decoded.group(1).replace(",", "")) > 0.9 * reference.width_px * reference.height_px


def test_capture_page_of_another_user_is_not_found(client_bob, rig, captures):
    reference, _ = captures
    assert client_bob.get(f"/captures/{reference.pk}/").status_code == 404


def test_measurement_page_shows_the_sigma_map(client_alice, rig, captures, run_jobs):
    from metrology.measurements.services import request_measurement

    reference, obj = captures
    with run_jobs():
        measurement = request_measurement(
            owner=reference.owner, rig=rig, reference_id=reference.pk, object_id=obj.pk, options={"sigma": True}
        )
    html = client_alice.get(f"/measurements/{measurement.pk}/").content.decode()
    assert "Per-point uncertainty" in html
    assert figure_data(html, "sigma_map")["data"][0]["type"] == "heatmap"
    assert "sigma.npy" in html  # the download
    # the form offers it
    form = client_alice.get(f"/measurements/new/?rig={rig.pk}").content.decode()
    assert 'name="sigma"' in form


def test_capture_page_and_api_show_the_codec_self_check(client_alice, rig, alice):
    capture = upload_capture(
        owner=alice,
        rig=rig,
        upload=SimpleUploadedFile("ref.zip", codec_zip(codec_images(0.0)), "application/zip"),
        role="reference",
    )
    html = client_alice.get(f"/captures/{capture.pk}/").content.decode()
    assert "Codec self-check" in html and 'class="badge codec-consistent">consistent<' in html
    data = client_alice.get(f"/api/captures/{capture.pk}/").json()
    assert data["codec_check"]["u"]["status"] == "consistent"
    assert set(data["codec_check"]["u"]) >= {"status", "offset_px", "outside_share", "message"}


def test_a_measurement_of_an_inconsistent_capture_fails_unless_allowed(client_alice, rig, alice, run_jobs):
    from metrology.measurements.models import Measurement

    wrong = json.loads(json.dumps(CODEC))
    wrong["axes"]["u"]["phase"][0]["origin"] = 15.5  # the frames were made with -0.5: half a period off
    ids = []
    for name, role, z_mm in (("ref.zip", "reference", 0.0), ("obj.zip", "object", 5.0)):
        upload = SimpleUploadedFile(name, codec_zip(codec_images(z_mm), wrong), "application/zip")
        ids.append(upload_capture(owner=alice, rig=rig, upload=upload, role=role).pk)
    page = client_alice.get(f"/captures/{ids[1]}/").content.decode()
    assert 'class="badge codec-inconsistent">inconsistent<' in page
    assert "Origin should be -0.5, not 15.5 (axes.u.phase[0].origin)" in page
    form = client_alice.get(f"/measurements/new/?rig={rig.pk}").content.decode()
    assert 'name="allow_inconsistent_codec"' in form
    for allow in (False, True):
        post = {"reference": ids[0], "object": ids[1], **({"allow_inconsistent_codec": "on"} if allow else {})}
        with run_jobs():
            answer = client_alice.post(f"/measurements/new/?rig={rig.pk}", post)
        assert answer.status_code == 302
        measurement = Measurement.objects.latest("pk")
        assert measurement.options["allow_inconsistent_codec"] is allow
        measurement.job.refresh_from_db()
        if allow:
            assert measurement.job.status == "done"
            measurement.refresh_from_db()
            assert measurement.statistics["codec_check"]["u"]["status"] == "inconsistent"
        else:
            assert measurement.job.status == "failed"
            assert "does not match its codec" in measurement.job.error
            assert "Origin should be -0.5, not 15.5" in measurement.job.error
