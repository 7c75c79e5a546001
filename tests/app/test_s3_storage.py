"""The application's storage on a real S3-protocol server (moto_server, tests/s3.py): the Django
storage API against it, and a measurement whose captures, results and derived files live in a bucket."""

from __future__ import annotations

import io

import numpy as np
import pytest
import requests
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage

from metrology.core.geometry.crossed_axes import Rig
from metrology.jobs.models import Job
from metrology.measurements.derived import derived_name
from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload


@pytest.fixture
def bucket(s3, settings) -> str:
    """A fresh bucket, made the default storage of this test."""
    name = s3.bucket()
    settings.STORAGES = s3.storages(name)
    settings.GCPS_S3_BUCKET = name
    return name


def test_the_default_storage_is_s3_when_the_bucket_is_set(bucket):
    from storages.backends.s3 import S3Storage

    assert isinstance(default_storage, S3Storage) and default_storage.bucket_name == bucket


def test_upload_download_ranges_delete_and_missing_objects(bucket, s3):
    data = bytes(range(256)) * 4096  # 1 MiB
    name = default_storage.save("derived/a.bin", ContentFile(data))
    assert name == "derived/a.bin" and s3.objects(bucket) == {"derived/a.bin": len(data)}
    assert default_storage.exists(name) and default_storage.size(name) == len(data)
    with default_storage.open(name, "rb") as handle:
        assert handle.read() == data
    with default_storage.open(name, "rb") as handle:  # a seek then a read: a ranged GET
        handle.seek(1000)
        assert handle.read(10) == data[1000:1010]
    assert default_storage.listdir("derived") == ([], ["a.bin"])
    # private: no anonymous read; a presigned URL reads it, with ranges answered by the server
    assert requests.get(f"{s3.endpoint_url}/{bucket}/{name}", timeout=10).status_code == 403
    url = default_storage.url(name)
    assert "X-Amz-Signature=" in url
    assert requests.get(url, timeout=10).content == data
    part = requests.get(url, headers={"Range": "bytes=100-199"}, timeout=10)
    assert part.status_code == 206 and part.content == data[100:200]
    assert part.headers["Content-Range"] == f"bytes 100-199/{len(data)}"
    # overwritten in place (file_overwrite): one object
    assert default_storage.save(name, ContentFile(b"new")) == name
    assert s3.objects(bucket) == {name: 3}
    default_storage.delete(name)
    assert not default_storage.exists(name) and s3.objects(bucket) == {}
    assert not default_storage.exists("derived/never.bin")
    with pytest.raises(FileNotFoundError):
        default_storage.open("derived/never.bin", "rb").read()
    default_storage.delete("derived/never.bin")  # deleting a missing object is harmless


@pytest.mark.django_db(transaction=True)
def test_a_measurement_stores_everything_in_the_bucket_and_downloads_from_it(api, rig, bucket, s3, media_root):
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, block_heights(), bit_depth=16)), "object")
    started = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    assert started.status_code == 202, started.content
    measurement_id = started.json()["id"]
    assert api.get(f"/api/measurements/{measurement_id}/").json()["status"] == "done"
    measurement = Measurement.objects.get(pk=measurement_id)
    keys = s3.objects(bucket)
    assert measurement.height_npy.name in keys and measurement.object.file.name in keys
    assert [p for p in media_root.rglob("*") if p.is_file()] == []  # nothing on the local disk

    # a stored file: a redirect to a short-lived presigned URL that carries the attachment name
    height = api.get(f"/api/measurements/{measurement_id}/height.npy")
    assert height.status_code == 302 and "X-Amz-Expires=300" in height["Location"]
    fetched = requests.get(height["Location"], timeout=10)
    assert fetched.headers["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-height.npy"'
    z = np.load(io.BytesIO(fetched.content))
    assert z.shape == (SMALL_RIG["height_px"], SMALL_RIG["width_px"]) and np.isfinite(z).mean() > 0.5

    # a derived mesh: built by its job (inline in the tests) into the bucket, then redirected to
    mesh = api.get(f"/api/measurements/{measurement_id}/mesh.ply")
    assert mesh.status_code == 302, mesh
    assert derived_name(measurement, "mesh.ply") in s3.objects(bucket)
    assert Job.objects.get(kind=Job.Kind.DERIVED_FILE).status == Job.Status.DONE
    ply = requests.get(mesh["Location"], timeout=10)
    assert ply.status_code == 200 and ply.content.startswith(b"ply\nformat binary_little_endian")
    part = requests.get(mesh["Location"], headers={"Range": "bytes=0-2"}, timeout=10)
    assert part.status_code == 206 and part.content == b"ply"
    assert [p for p in media_root.rglob("*") if p.is_file()] == []
