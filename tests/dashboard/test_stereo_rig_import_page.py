"""The rig pages' import of a two-camera OpenCV calibration (issue 24): the same recognition as
``gcps rig import`` (:func:`metrology.core.rig_import.import_rig`), so a file with ``M1 D1 M2 D2 R T``
becomes a stereo rig (the Rigs page makes one) and the summary names the nodes it read."""

from __future__ import annotations

import cv2
import numpy as np
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.core.geometry.stereo import StereoRig

M1 = np.array([[402.5, 0.0, 160.25], [0.0, 401.0, 119.5], [0.0, 0.0, 1.0]])
M2 = np.array([[398.0, 0.0, 158.0], [0.0, 399.5, 121.0], [0.0, 0.0, 1.0]])
D = np.array([[-0.05, 0.02, 0.0, 0.0, 0.0]])
R = cv2.Rodrigues(np.array([0.0, -0.2, 0.0]))[0]
T = np.array([[-120.0, 0.5, 10.0]])


def _stereo_file(path):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for node, value in {"S": np.array([[320.0, 240.0]]), "M1": M1, "D1": D, "M2": M2, "D2": D, "R": R, "T": T}.items():
        fs.write(node, value)
    fs.release()
    return path


def test_the_rig_pages_import_reads_a_two_camera_file_as_a_stereo_rig(tmp_path):
    """:func:`metrology.rigs.services.read_calibration_upload` (the import of the Rigs page and of a
    rig's page) gives the stereo rig and a summary naming each node, under the uploaded file's name."""
    from metrology.rigs.services import read_calibration_upload

    path = _stereo_file(tmp_path / "stereo.yml")
    upload = SimpleUploadedFile("stereo.yml", path.read_bytes())
    model, summary = read_calibration_upload(upload, projector_size=(1280.0, 800.0))
    assert isinstance(model, StereoRig)
    data = model.to_dict()
    assert np.array_equal(data["cameras"][0]["K"], M1) and np.array_equal(data["cameras"][1]["K"], M2)
    assert np.array_equal(data["cameras"][1]["R"], R) and np.array_equal(data["cameras"][1]["T"], T.ravel())
    assert data["projector"] == {"width": 1280, "height": 800}
    assert summary["model"] == "stereo" and summary["camera_size"]["value"] == [320, 240]
    assert summary["read"] == {
        "camera0_K": "stereo.yml#M1",
        "camera0_dist": "stereo.yml#D1",
        "camera1_K": "stereo.yml#M2",
        "camera1_dist": "stereo.yml#D2",
        "R": "stereo.yml#R",
        "T": "stereo.yml#T",
    }


def test_the_rigs_page_imports_a_two_camera_file_as_a_stereo_rig(client_alice, alice, tmp_path):
    """The Rigs page's calibration-file form: a stereo rig, and its page names the nodes it read."""
    from html import unescape

    from metrology.rigs.models import Rig

    path = _stereo_file(tmp_path / "stereo.yml")
    done = client_alice.post(
        "/rigs/",
        {
            "action": "calibration",
            "import-name": "pair",
            "import-calibration_file": SimpleUploadedFile("stereo.yml", path.read_bytes()),
            "import-projector_width": 1280,
            "import-projector_height": 800,
        },
    )
    errors = [line for line in unescape(done.content.decode()).splitlines() if "errorlist" in line]
    assert done.status_code == 302, errors
    rig = Rig.objects.get(owner=alice)
    assert isinstance(rig.to_core(), StereoRig) and rig.name == "pair"
    page = unescape(client_alice.get(done["Location"]).content.decode())
    for key, node in (("camera0_K", "M1"), ("camera1_K", "M2"), ("R", "R"), ("T", "T")):
        assert f"{key} from {node}" in page, (key, node)
