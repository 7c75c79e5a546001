"""``python manage.py demo``: a virtual rig, simulated captures, a measurement, a calibration, a characterization.

Works on the embedded default (jobs run in-process) and with workers (it waits for their jobs).
Running it again adds nothing once a run has finished: it finds the demo rig and its own results
(the first finished measurement, calibration and characterization of that rig, not whatever was
made on it since) and prints them again (a run stopped part-way is completed on the same rig).
Its output is its summary only: the log lines of the jobs it runs in-process (Celery's
"Task ... succeeded") are kept out of it.
"""

from __future__ import annotations

import logging
import os
import time

from django.contrib.auth import get_user_model
from django.core.management.base import BaseCommand, CommandError
from rest_framework.authtoken.models import Token

from metrology.calibrations.models import Calibration
from metrology.calibrations.services import request_calibration
from metrology.captures.services import create_session, request_simulated_capture
from metrology.captures.simulation import PRESETS
from metrology.characterizations.models import Characterization
from metrology.characterizations.services import request_characterization
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.services import request_measurement
from metrology.rigs.models import Rig
from metrology.rigs.services import create_rig

NOISE = PRESETS["realistic"]  # the API's and the dashboard's default
RIG_NAME = "virtual rig (paper geometry)"
QUIET_LOGGERS = ("celery", "metrology.jobs")
"""Loggers whose INFO lines (a job run in-process) would interleave with the demo's summary."""


class Command(BaseCommand):
    help = "Run the demo on a virtual rig and print where to look at the results."

    def add_arguments(self, parser) -> None:
        parser.add_argument("--user", default="demo")
        parser.add_argument("--width", type=int, default=320)
        parser.add_argument("--height", type=int, default=240)
        parser.add_argument("--timeout", type=float, default=900.0, help="Seconds to wait for the jobs")

    def handle(self, *args, user: str, width: int, height: int, timeout: float, **options) -> None:
        quiet = [logging.getLogger(name) for name in QUIET_LOGGERS]
        levels = [logger.level for logger in quiet]
        for logger in quiet:
            logger.setLevel(logging.WARNING)  # warnings and errors still show
        try:
            self.run(user=user, width=width, height=height, timeout=timeout)
        finally:
            for logger, level in zip(quiet, levels, strict=True):
                logger.setLevel(level)

    def run(self, *, user: str, width: int, height: int, timeout: float) -> None:
        owner, created = get_user_model().objects.get_or_create(username=user)
        if created:  # a throw-away demo account: log in to the dashboard as demo / demo
            owner.set_password(user)
            owner.save(update_fields=["password"])
            self.say(f"created user {user!r} with password {user!r} (for the dashboard's login page)")
        token, _ = Token.objects.get_or_create(user=owner)
        self.timeout = timeout
        rig = (
            Rig.objects.filter(owner=owner, name=RIG_NAME, parameters__width_px=width, parameters__height_px=height)
            .order_by("pk")
            .first()
        )
        if rig is not None:
            finished = self.finished_results(rig)
            if finished is not None:
                self.say(f"the demo has run before: rig {rig.pk} and its results are kept, nothing added")
                self.report(*finished, token=token)
                return
            self.say(f"rig {rig.pk}: completing an earlier demo run that did not finish")
        else:
            rig = self.create_demo_rig(owner, width, height)
        self.run_demo(owner, rig, token)

    def create_demo_rig(self, owner, width: int, height: int) -> Rig:
        rig = create_rig(
            owner=owner,
            data={
                "name": RIG_NAME,
                "L_mm": 1022.0,
                "d_mm": 352.0,
                "alpha_rad": 0.332,
                "fw_mm": 500.0,
                "nlp": 128,
                "width_px": width,
                "height_px": height,
            },
        )
        self.say(f"rig {rig.pk}: {rig.to_core().summary()}")
        return rig

    @staticmethod
    def finished_results(rig: Rig) -> tuple[Measurement, Calibration, Characterization] | None:
        """The demo's own results on its rig, if all exist: the first finished measurement,
        calibration and characterization of ``rig`` (the demo made the rig and those first; what a
        person made on the rig later is not the demo's)."""
        done = Job.Status.DONE
        found = (
            Measurement.objects.filter(rig=rig, job__status=done).order_by("pk").first(),
            Calibration.objects.filter(rig=rig, job__status=done).order_by("pk").first(),
            Characterization.objects.filter(rig=rig, job__status=done).order_by("pk").first(),
        )
        if found[0] is None or found[1] is None or found[2] is None:
            return None
        return found[0], found[1], found[2]

    def run_demo(self, owner, rig: Rig, token: Token) -> None:
        def simulate(role, scene, seed, **extra):
            return request_simulated_capture(
                owner=owner, rig=rig, role=role, scene=scene, options={**NOISE, "seed": seed}, **extra
            )

        reference = simulate("reference", {"name": "reference"}, 1)
        obj = simulate("object", {"name": "two_spheres"}, 2)
        master = simulate("master", {"name": "block", "top_mm": 40.0}, 3)
        stage_session = create_session(owner=owner, rig=rig, name="virtual stage 0-16 mm")
        stage = [
            simulate("stage", {"name": "stage"}, 10 + 3 * i + r, z_in_mm=z, repeat=r, session_id=stage_session.pk)
            for i, z in enumerate((0.0, 4.0, 8.0, 12.0, 16.0))
            for r in range(3)
        ]
        self.wait([c.job_id for c in (reference, obj, master, *stage)], "simulated captures")

        measurement = request_measurement(owner=owner, rig=rig, reference_id=reference.pk, object_id=obj.pk)
        calibration = request_calibration(
            owner=owner,
            rig=rig,
            reference_id=reference.pk,
            master_id=master.pk,
            master_height_mm=40.0,
            method="lsq",
            initial={"L_mm": 1080.0, "alpha_rad": 0.4871},
        )
        characterization = request_characterization(
            owner=owner, rig=rig, reference_id=reference.pk, session_id=stage_session.pk
        )
        self.wait(
            [measurement.job_id, calibration.job_id, characterization.job_id],
            "measurement, calibration, characterization",
        )
        measurement.refresh_from_db()
        calibration.refresh_from_db()
        characterization.refresh_from_db()
        self.report(measurement, calibration, characterization, token=token)

    def report(
        self, measurement: Measurement, calibration: Calibration, characterization: Characterization, *, token: Token
    ) -> None:
        owner = token.user
        stats = measurement.statistics
        self.say(
            f"measurement {measurement.pk}: {100 * stats.get('valid_fraction', 0):.1f} % of pixels measured, "
            f"heights {stats.get('min_mm') or 0:.2f} to {stats.get('max_mm') or 0:.2f} mm"
        )
        result = calibration.result
        self.say(
            f"calibration {calibration.pk}: from L = 1080 mm, alpha = 0.4871 rad "
            f"to L = {result.get('L_mm', 0):.2f} mm, alpha = {result.get('alpha_rad', 0):.4f} rad "
            "(true 1022 mm, 0.332 rad)"
        )
        mean_um = 1000 * (characterization.overall_mean_error_mm or 0)
        sigma_um = 1000 * (characterization.overall_std_error_mm or 0)
        self.say(f"characterization {characterization.pk}: mean error {mean_um:.1f} um, sigma {sigma_um:.1f} um")
        self.say(f"API token of user {owner.username!r}: {token.key}")
        base = f"http://127.0.0.1:{os.environ.get('PORT') or 8000}"
        self.say(f"dashboard: {base}/ (log in as {owner.username!r}; password {owner.username!r} if the demo made it)")
        self.say(f"try: curl -H 'Authorization: Token {token.key}' {base}/api/measurements/{measurement.pk}/")

    def wait(self, job_ids: list[int], what: str) -> None:
        deadline = time.monotonic() + self.timeout
        while True:
            jobs = list(Job.objects.filter(pk__in=job_ids))
            failed = [job for job in jobs if job.status == Job.Status.FAILED]
            if failed:
                raise CommandError(f"{what}: job {failed[0].pk} failed: {failed[0].error}")
            if all(job.status == Job.Status.DONE for job in jobs):
                self.say(f"{what}: {len(jobs)} job(s) done")
                return
            if time.monotonic() > deadline:
                raise CommandError(f"{what}: jobs not done after {self.timeout:.0f} s (is a worker running?)")
            time.sleep(0.5)

    def say(self, text: str) -> None:
        self.stdout.write(text)
