"""Real captures through the application: the kamino410 procam-calibration sample (5 poses of a 9x7
inner-corner chessboard of 75-unit squares, gray code with inverses on both axes, 1280x1024 camera,
1024x768 projector; MIT licensed, kept outside the repository) uploaded as board captures, calibrated
by the job: camera fx within 1 % of 3452 (the dataset's own program: 3452.4) and stereo RMS at most
0.7 px, as `gcps calibrate-procam` gives (tests/core/procam/test_kamino410_procam.py).

Skipped (with the reason) when the dataset folder is absent, except under ``CI=true`` where its
absence fails.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from django.core.files import File

from metrology.calibrations.models import ProcamCalibration
from metrology.calibrations.procam_services import apply_procam_calibration, request_procam_calibration
from metrology.captures.services import upload_capture
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG
from tests.datasets import dataset_path, require_dataset

ROOT = Path(__file__).resolve().parents[2]
DATASET = dataset_path("kamino410-procam-calibration", "sample_data")
CODEC = ROOT / "examples" / "kamino410-procam.codec.json"

pytestmark = [pytest.mark.slow, pytest.mark.django_db(transaction=True)]


@pytest.fixture(scope="module")
def pose_zips(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    require_dataset(DATASET / "capture_0", "kamino410 procam dataset")
    out = tmp_path_factory.mktemp("kamino-zips")
    zips = []
    for index in range(5):
        path = out / f"capture_{index}.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:  # PNGs: already compressed
            for frame in sorted((DATASET / f"capture_{index}").glob("graycode_*.png")):
                archive.write(frame, frame.name)
            archive.write(CODEC, "codec.json")
        zips.append(path)
    return zips


def test_kamino410_poses_calibrate_through_the_job(db, pose_zips, django_user_model):
    owner = django_user_model.objects.create_user("kamino")
    rig = create_rig(owner=owner, data={**SMALL_RIG, "width_px": 1280, "height_px": 1024, "name": "kamino410"})
    ids = []
    for path in pose_zips:
        with path.open("rb") as handle:
            ids.append(upload_capture(owner=owner, rig=rig, upload=File(handle, name=path.name), role="board").pk)
    calibration = request_procam_calibration(owner=owner, rig=rig, pose_ids=ids, board="chessboard:9x7:75")
    calibration = ProcamCalibration.objects.get(pk=calibration.pk)
    assert calibration.job.status == "done", calibration.job.error
    report = calibration.report
    assert report["poses_used"] == 5 and report["camera_size"] == [1280, 1024]
    assert report["projector_size"] == [1024, 768]
    assert abs(calibration.rig_file["camera"]["K"][0][0] / 3452.0 - 1) < 0.01
    assert report["stereo_rms_px"] <= 0.7
    assert [p["name"] for p in report["poses"]] == [f"capture_{i}.zip" for i in range(5)]
    apply_procam_calibration(calibration=calibration)
    rig.refresh_from_db()
    assert rig.model == "pinhole" and rig.rig_file() == calibration.rig_file
    assert (rig.width_px, rig.height_px) == (1280, 1024)
