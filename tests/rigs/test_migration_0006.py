"""The migration to ``Rig.model`` + ``Rig.parameters`` (rigs 0006) keeps every rig and its history,
on a database holding rigs of both models, and migrates back. (Results keep the rig values they
were made with in their own rows, ``rig_values``, which the migration does not touch.)

The database is migrated back to rigs 0005 (the seven crossed-axes columns beside a ``pinhole``
rig file), filled through the historical models of that state, then migrated forward; the rigs
are then read with today's models and the core.
"""

from __future__ import annotations

import pytest
from django.db import connection
from django.db.migrations.executor import MigrationExecutor

from tests.app.stacks import SMALL_RIG
from tests.pinhole_stacks import RIG as PINHOLE_RIG

pytestmark = pytest.mark.django_db(transaction=True)

BEFORE = [("rigs", "0005_rigparameters_restored")]
SEVEN = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")


def migrate(targets):
    executor = MigrationExecutor(connection)
    executor.loader.build_graph()
    executor.migrate(targets)
    return executor.loader.project_state(targets).apps


def leaves():
    return MigrationExecutor(connection).loader.graph.leaf_nodes()


def fill_old_state(apps):
    """Two rigs as 0005 stored them: a crossed-axes one with a calibration and a restore in its
    history, and a pinhole one converted from crossed-axes values by a calibration."""
    User = apps.get_model("auth", "User")
    Rig = apps.get_model("rigs", "Rig")
    RigParameters = apps.get_model("rigs", "RigParameters")
    owner = User.objects.create(username="carol")
    crossed = Rig.objects.create(owner=owner, name="bench", model="crossed_axes", extra={"lens": "25 mm"}, **SMALL_RIG)
    first = RigParameters.objects.create(rig=crossed, values=dict(SMALL_RIG), source="created")
    calibrated = {**SMALL_RIG, "L_mm": SMALL_RIG["L_mm"] + 3.5, "alpha_rad": SMALL_RIG["alpha_rad"] - 0.002}
    RigParameters.objects.create(rig=crossed, values=calibrated, source="calibration")
    RigParameters.objects.create(rig=crossed, values=dict(SMALL_RIG), source="restored", restored_from=first)
    pinhole_file = PINHOLE_RIG.to_dict()
    camera = pinhole_file["camera"]
    pinhole = Rig.objects.create(
        owner=owner,
        name="calibrated",
        model="pinhole",
        pinhole=pinhole_file,
        width_px=camera["width_px"],
        height_px=camera["height_px"],
    )
    RigParameters.objects.create(rig=pinhole, values=dict(SMALL_RIG), source="created")
    RigParameters.objects.create(rig=pinhole, values=pinhole_file, source="calibration")
    return owner.pk, crossed.pk, pinhole.pk, calibrated, pinhole_file


def test_rigs_of_both_models_keep_their_values_history_and_results_and_migrate_back():
    from metrology.core.geometry.crossed_axes import Rig as CrossedAxes
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.rigs.models import Rig, RigParameters

    old_apps = migrate(BEFORE)
    _, crossed_id, pinhole_id, calibrated, pinhole_file = fill_old_state(old_apps)
    migrate(leaves())

    crossed, pinhole = Rig.objects.get(pk=crossed_id), Rig.objects.get(pk=pinhole_id)
    assert (crossed.model, crossed.parameters) == ("crossed_axes", dict(SMALL_RIG))
    assert crossed.extra == {"lens": "25 mm"} and crossed.name == "bench"
    assert crossed.to_core() == CrossedAxes.from_dict(SMALL_RIG)
    assert pinhole.model == "pinhole"
    assert pinhole.parameters == {k: v for k, v in pinhole_file.items() if k != "model"}
    assert pinhole.to_core() == PinholeRig.from_dict(pinhole_file)
    assert pinhole.shape == PINHOLE_RIG.shape

    history = list(RigParameters.objects.filter(rig=crossed).order_by("id"))
    assert [h.source for h in history] == ["created", "calibration", "restored"]
    assert [h.values for h in history] == [dict(SMALL_RIG), calibrated, dict(SMALL_RIG)]
    assert history[2].restored_from_id == history[0].pk
    assert history[1].to_core() == CrossedAxes.from_dict(calibrated)  # a file without its model key
    pinhole_history = list(RigParameters.objects.filter(rig=pinhole).order_by("id"))
    assert [h.to_core() for h in pinhole_history] == [CrossedAxes.from_dict(SMALL_RIG), PINHOLE_RIG]

    # and back: the old columns hold the values again
    old_apps = migrate(BEFORE)
    OldRig = old_apps.get_model("rigs", "Rig")
    old_crossed, old_pinhole = OldRig.objects.get(pk=crossed_id), OldRig.objects.get(pk=pinhole_id)
    assert {name: getattr(old_crossed, name) for name in SEVEN} == dict(SMALL_RIG)
    assert old_pinhole.pinhole == pinhole_file
    assert (old_pinhole.width_px, old_pinhole.height_px) == (PINHOLE_RIG.shape[1], PINHOLE_RIG.shape[0])
    migrate(leaves())
