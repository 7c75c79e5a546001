# ruff: noqa: RUF012  (Django migration lists)
"""A rig stores its model and the model's parameters (one JSON field) instead of the crossed-axes
model's seven columns beside a pinhole rig file.

Data: a crossed-axes rig's parameters are its seven values; a pinhole rig's, its rig file without
the ``model`` key. The history entries and every result keep the values they were stored with.
Reversible: migrating back to 0005 puts the values in the old columns again (a pinhole rig's
file back in ``pinhole``, its camera size in ``width_px``/``height_px``).
"""

from django.db import migrations, models

import metrology.rigs.models

SEVEN = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")


def to_parameters(apps, schema_editor):
    Rig = apps.get_model("rigs", "Rig")
    for rig in Rig.objects.all():
        if rig.model == "pinhole":
            rig.parameters = {key: value for key, value in (rig.pinhole or {}).items() if key != "model"}
        else:
            rig.parameters = {name: getattr(rig, name) for name in SEVEN}
        rig.save(update_fields=["parameters"])


def to_columns(apps, schema_editor):
    Rig = apps.get_model("rigs", "Rig")
    for rig in Rig.objects.all():
        values = dict(rig.parameters or {})
        if rig.model == "pinhole":
            rig.pinhole = {"model": "pinhole", **values}
            camera = values.get("camera") or {}
            rig.width_px, rig.height_px = camera.get("width_px"), camera.get("height_px")
        else:
            for name in SEVEN:
                setattr(rig, name, values.get(name))
        rig.save()


class Migration(migrations.Migration):
    dependencies = [
        ("rigs", "0005_rigparameters_restored"),
    ]

    operations = [
        migrations.AddField(
            model_name="rig",
            name="parameters",
            field=models.JSONField(
                default=dict, help_text="The model's values: its rig file without the model key (validated by the core)"
            ),
        ),
        # nullable while both forms exist, so that migrating back can add the columns to filled tables
        migrations.AlterField(model_name="rig", name="width_px", field=models.PositiveIntegerField(null=True)),
        migrations.AlterField(model_name="rig", name="height_px", field=models.PositiveIntegerField(null=True)),
        migrations.RunPython(to_parameters, to_columns),
        migrations.RemoveField(model_name="rig", name="L_mm"),
        migrations.RemoveField(model_name="rig", name="d_mm"),
        migrations.RemoveField(model_name="rig", name="alpha_rad"),
        migrations.RemoveField(model_name="rig", name="fw_mm"),
        migrations.RemoveField(model_name="rig", name="nlp"),
        migrations.RemoveField(model_name="rig", name="width_px"),
        migrations.RemoveField(model_name="rig", name="height_px"),
        migrations.RemoveField(model_name="rig", name="pinhole"),
        migrations.AlterField(
            model_name="rig",
            name="model",
            field=models.CharField(
                choices=metrology.rigs.models.model_choices,
                default="crossed_axes",
                help_text="The rig's geometric model",
                max_length=32,
            ),
        ),
        migrations.AlterField(
            model_name="rigparameters",
            name="values",
            field=models.JSONField(
                help_text="The rig file of the values (read by the core; a crossed-axes file may lack its model key)"
            ),
        ),
    ]
