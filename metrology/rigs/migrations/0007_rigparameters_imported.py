# ruff: noqa: RUF012  (Django migration lists)
"""History entries may say that a calibration file was imported into the rig (its rig page)."""

from django.db import migrations, models


class Migration(migrations.Migration):
    dependencies = [
        ("rigs", "0006_rig_parameters"),
    ]

    operations = [
        migrations.AlterField(
            model_name="rigparameters",
            name="source",
            field=models.CharField(
                choices=[
                    ("created", "Created"),
                    ("calibration", "Calibration applied"),
                    ("manual", "Edited"),
                    ("restored", "Restored from history"),
                    ("imported", "Imported from a calibration file"),
                ],
                max_length=16,
            ),
        ),
    ]
