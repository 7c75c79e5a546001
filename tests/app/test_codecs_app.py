"""Codecs through the REST API: a rig's default codec, uploads carrying their own codec.json,
measurement jobs of captures of a codec other than gcps-v1 (docs/codecs.md)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.captures.models import Capture
from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.crossed_axes import Rig
from metrology.measurements.models import Measurement
from tests.app.codec_stacks import CODEC, codec_images, codec_zip
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import post_capture
from tests.conftest import stored_files

# Jobs are enqueued on commit: these tests need real commits.
pytestmark = pytest.mark.django_db(transaction=True)


def test_rig_default_codec_is_gcps_v1_and_settable(api, rig):
    assert rig["codec"] == "gcps-v1"
    url = f"/api/rigs/{rig['id']}/codec/"
    assert api.get(url).json() == {"codec": "gcps-v1"}
    response = api.put(url, {"codec": CODEC}, format="json")
    assert response.status_code == 200, response.content
    assert api.get(f"/api/rigs/{rig['id']}/").json()["codec"] == codec_from_dict(CODEC).to_dict()
    assert api.put(url, {"codec": "gcps-v1:1280x800"}, format="json").json() == {"codec": "gcps-v1:1280x800"}
    for bad, words in (
        ({"codec": {**CODEC, "framez": 3}}, "framez"),
        ({"codec": {**CODEC, "frames": 5}}, "frame"),
        ({"codec": "gcps-v2"}, "unknown built-in codec 'gcps-v2'"),
        ({"codec": 7}, "a codec is a built-in name"),
    ):
        response = api.put(url, bad, format="json")
        assert response.status_code == 400, (bad, response.content)
        assert words in response.json()["error"], response.json()
    assert api.get(url).json() == {"codec": "gcps-v1:1280x800"}  # unchanged by the refusals
    created = api.post("/api/rigs/", {**SMALL_RIG, "codec": CODEC}, format="json")
    assert created.status_code == 201 and created.json()["codec"]["codec"] == "gcps-codec/1"
    assert "codec" not in created.json()["extra"]
    refused = api.post("/api/rigs/", {**SMALL_RIG, "codec": {"codec": "gcps-codec/1"}}, format="json")
    assert refused.status_code == 400 and "codec" in refused.json()["error"]


def test_a_new_rig_gets_its_projectors_default_codec_without_building_tables(api):
    """A distorted pinhole rig (1280x1024 camera, the issue-22 projector) created without a codec
    gets gcps-v1 at its projector's size, read off the model: no table is prepared for it (building
    them took 0.5 s of CPU at 640x480 and seconds at 1280x1024, in the request)."""
    from metrology.core.geometry import pinhole

    rig_file = {
        "model": "pinhole",
        "camera": {
            "width_px": 1280,
            "height_px": 1024,
            "K": [[1754.1124, 0, 645.3847], [0, 1752.9028, 529.4902], [0, 0, 1]],
            "dist": [-0.0711684, -0.1850473, 0.00023178, 0.00055408, 1.8431788],
        },
        "projector": {
            "width": 1920,
            "height": 1080,
            "K": [[2496.6331, 0, 990.3217], [0, 2495.8150, 547.0096], [0, 0, 1]],
            "dist": [-0.0424964, -0.6599270, -0.00068874, 0.00105835, 3.4566275],
        },
        "R": [
            [0.99592406, -0.00963023, 0.08968011],
            [0.01005291, 0.99994038, -0.00426267],
            [-0.08963372, 0.00514685, 0.99596150],
        ],
        "T": [-108.18012, -5.15673, -15.73173],
    }
    before = pinhole._prepare_cached.cache_info()
    created = api.post("/api/rigs/", rig_file, format="json")
    assert created.status_code == 201, created.content
    assert created.json()["codec"] == "gcps-v1:1920x1080"
    after = pinhole._prepare_cached.cache_info()
    assert (after.hits, after.misses) == (before.hits, before.misses)


def test_upload_with_its_codec_json_is_stored_with_its_codec(api, rig, media_root):
    response = post_capture(api, rig["id"], codec_zip(codec_images(0.0)), "reference")
    assert response.status_code == 201, response.content
    capture = Capture.objects.get(pk=response.json()["id"])
    assert capture.codec == codec_from_dict(CODEC).to_dict() and capture.bit_depth == 16
    assert response.json()["codec"]["codec"] == "gcps-codec/1"
    # a gcps-v1 upload records the rig's default, gcps-v1
    plain = post_capture(api, rig["id"], stack_zip(render_images(Rig.from_dict(SMALL_RIG), 0.0)), "reference")
    assert plain.status_code == 201 and plain.json()["codec"] == "gcps-v1"


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: codec_zip(codec_images(0.0), {**CODEC, "colour": 1}), "colour"),
        (lambda: codec_zip(codec_images(0.0)[:23]), "holds 23 image files but the codec describes 24 frames"),
        (
            lambda: codec_zip(codec_images(0.0), {**CODEC, "axes": {"v": CODEC["axes"]["u"]}}),
            "does not code the projector's u axis",
        ),
        (lambda: codec_zip(codec_images(0.0)[:, :60, :80]), "the frames are 80x60 px but the rig is 160x120 px"),
        (lambda: codec_zip(codec_images(0.0), None), "GC_0"),  # no codec.json: the rig's gcps-v1 reader
    ],
)
def test_bad_codec_or_stack_unlike_its_codec_answers_400_and_stores_nothing(api, rig, media_root, make, words):
    response = post_capture(api, rig["id"], make(), "reference")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"], response.json()
    assert Capture.objects.count() == 0
    assert stored_files(media_root) == []


def test_a_job_measures_uploads_of_another_codec_to_the_exact_heights(api, rig, media_root):
    # the rig's default codec is the 12-step codec: uploads without codec.json use it
    assert api.put(f"/api/rigs/{rig['id']}/codec/", {"codec": CODEC}, format="json").status_code == 200
    reference = post_capture(api, rig["id"], codec_zip(codec_images(0.0), None), "reference")
    assert reference.status_code == 201, reference.content
    obj = post_capture(api, rig["id"], codec_zip(codec_images(block_heights())), "object")
    assert obj.status_code == 201, obj.content
    response = api.post(
        "/api/measurements/",
        {"rig": rig["id"], "reference": reference.json()["id"], "object": obj.json()["id"]},
        format="json",
    )
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    assert body["statistics"]["codec"]["codec"] == "gcps-codec/1"
    assert body["statistics"]["decoding"]["axes"]["u"]["decoded"] > 0
    assert {"height.npy", "height.tiff", "mesh.ply"} <= set(body["files"])
    download = api.get(f"/api/measurements/{body['id']}/height.npy")
    z = np.load(io.BytesIO(b"".join(download.streaming_content)))
    truth = block_heights()
    inner = np.zeros_like(truth, dtype=bool)
    inner[35:85, 45:115] = True
    inner[:20, :] = True
    ok = inner & np.isfinite(z)
    assert ok.sum() > 0.8 * inner.sum()
    # noise-free exact model: within 1 um of the block and the plane
    assert np.abs(z[ok] - truth[ok]).max() < 1e-3
    assert Measurement.objects.get(pk=body["id"]).rig_values == {"model": "crossed_axes", **SMALL_RIG}
    # a second measurement against the same reference reuses the kept (decoded) codec reference
    from metrology.captures.references import kept_references

    hits = kept_references().stats.hits
    again = api.post(
        "/api/measurements/",
        {"rig": rig["id"], "reference": reference.json()["id"], "object": obj.json()["id"]},
        format="json",
    )
    assert api.get(f"/api/measurements/{again.json()['id']}/").json()["status"] == "done"
    assert kept_references().stats.hits == hits + 1


def test_a_measurement_of_captures_of_two_codecs_is_refused(api, rig):
    reference = post_capture(api, rig["id"], stack_zip(render_images(Rig.from_dict(SMALL_RIG), 0.0)), "reference")
    obj = post_capture(api, rig["id"], codec_zip(codec_images(block_heights())), "object")
    response = api.post(
        "/api/measurements/",
        {"rig": rig["id"], "reference": reference.json()["id"], "object": obj.json()["id"]},
        format="json",
    )
    assert response.status_code == 400
    assert "another codec than the reference capture" in response.json()["error"]
    assert Measurement.objects.count() == 0


def test_measurement_with_sigma_stores_and_serves_the_uncertainty(api, rig):
    """options.sigma: the job stores sigma.npy (mm), finite exactly where heights are; 8-bit noise."""
    core = Rig.from_dict(SMALL_RIG)
    rng = np.random.default_rng(3)

    def noisy(z: float | np.ndarray) -> bytes:
        images = render_images(core, z).astype(np.float64) + rng.normal(0, 1.5, (11, *core.shape))
        return stack_zip(np.clip(np.rint(images), 0, 255).astype(np.uint8))

    reference = post_capture(api, rig["id"], noisy(0.0), "reference").json()["id"]
    obj = post_capture(api, rig["id"], noisy(block_heights()), "object").json()["id"]
    body = {"rig": rig["id"], "reference": reference, "object": obj, "options": {"sigma": True}}
    response = api.post("/api/measurements/", body, format="json")
    assert response.status_code == 202, response.content
    result = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert result["status"] == "done", result
    assert result["options"]["sigma"] is True and "sigma.npy" in result["files"]
    z = np.load(io.BytesIO(b"".join(api.get(result["files"]["height.npy"]).streaming_content)))
    sigma = np.load(io.BytesIO(b"".join(api.get(result["files"]["sigma.npy"]).streaming_content)))
    assert sigma.dtype == np.float32 and np.array_equal(np.isfinite(sigma), np.isfinite(z))
    # 1.5 grey levels on fringes of amplitude 0.4 x 255: tenths of a code, ~0.1 mm on the paper's rig
    assert 0.02 < result["statistics"]["sigma_mm_median"] < 0.3
    assert abs(np.nanmedian(sigma) - result["statistics"]["sigma_mm_median"]) < 1e-6
    bad = api.post("/api/measurements/", {**body, "options": {"sigma": "yes"}}, format="json")
    assert bad.status_code == 400 and "sigma must be true or false" in bad.json()["error"]
