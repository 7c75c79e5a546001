"""Restoring a rig's history entry (``POST /api/rigs/ID/history/ENTRY/restore/``): a crossed-axes rig
converted to a pinhole rig by a calibration comes back to its exact seven values, and the pinhole file
comes back again, each as a new ``restored`` entry pointing to the one it copies; nothing is deleted.
Refusals (the current entry, another rig's entry, another user's rig) change nothing."""

from __future__ import annotations

from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.rigs.models import Rig, RigParameters
from metrology.rigs.services import set_rig_model
from tests.app.procam_stacks import RIG_320, TRUE_RIG


def make_converted_rig(api) -> tuple[dict, dict]:
    """A crossed-axes 320x240 rig made a pinhole rig (as applying a projector-camera calibration does)."""
    created = api.post("/api/rigs/", {**RIG_320, "name": "bench"}, format="json").json()
    rig_file = TRUE_RIG.to_dict()
    set_rig_model(rig=Rig.objects.get(pk=created["id"]), model=TRUE_RIG, source="calibration")
    return api.get(f"/api/rigs/{created['id']}/").json(), rig_file


def test_restore_goes_back_to_crossed_axes_and_forth_to_pinhole(api):
    rig, rig_file = make_converted_rig(api)
    assert rig["model"] == "pinhole"
    created, converted = rig["history"]
    assert [created["source"], converted["source"]] == ["created", "calibration"]
    codec = rig["codec"]

    back = api.post(f"/api/rigs/{rig['id']}/history/{created['id']}/restore/")
    assert back.status_code == 200, back.content
    body = back.json()
    assert body["model"] == "crossed_axes" and body["pinhole"] is None and body["codec"] == codec
    for name, value in RIG_320.items():  # the very values, not re-derived ones
        assert body[name] == value, name
    assert [e["source"] for e in body["history"]] == ["created", "calibration", "restored"]
    assert body["history"][-1]["restored_from"] == created["id"]
    assert body["history"][-1]["values"] == created["values"]
    core = Rig.objects.get(pk=rig["id"]).to_core()  # measurements use it: the paper's model again
    assert isinstance(core, CoreRig) and core.L_mm == RIG_320["L_mm"]

    forth = api.post(f"/api/rigs/{rig['id']}/history/{converted['id']}/restore/").json()
    assert forth["model"] == "pinhole" and forth["pinhole"] == converted["values"]
    assert forth["pinhole"] == TRUE_RIG.to_dict() == rig_file
    assert (forth["width_px"], forth["height_px"]) == (320, 240)
    assert [e["restored_from"] for e in forth["history"]] == [None, None, created["id"], converted["id"]]
    assert RigParameters.objects.filter(rig_id=rig["id"]).count() == 4


def test_refused_restores_change_nothing(api, other_api):
    rig, _ = make_converted_rig(api)
    current = rig["history"][-1]["id"]
    refused = api.post(f"/api/rigs/{rig['id']}/history/{current}/restore/")
    assert refused.status_code == 400
    assert refused.json()["error"] == f"history entry {current} already holds rig {rig['id']}'s current values"

    other = api.post("/api/rigs/", {**RIG_320, "name": "other"}, format="json").json()
    foreign = other["history"][0]["id"]
    refused = api.post(f"/api/rigs/{rig['id']}/history/{foreign}/restore/")
    assert refused.status_code == 400 and refused.json()["error"] == f"rig {rig['id']} has no history entry {foreign}"

    first = rig["history"][0]["id"]
    assert other_api.post(f"/api/rigs/{rig['id']}/history/{first}/restore/").status_code == 404
    after = api.get(f"/api/rigs/{rig['id']}/").json()
    assert after["model"] == "pinhole" and after["history"] == rig["history"]
