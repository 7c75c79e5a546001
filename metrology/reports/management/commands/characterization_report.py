"""``python manage.py characterization_report RIG``: a characterization report of a rig, now or on a schedule.

RIG is the rig's id or its name. Without a schedule option the report is produced at once (in this
process, or by the worker that takes its job first) and its stored path, page and summary printed.
With ``--schedule-every SECONDS`` or ``--schedule-crontab "m h dom mon dow"`` a Celery beat schedule
is stored instead (``--unschedule`` removes it).
"""

from __future__ import annotations

from django.core.management.base import BaseCommand, CommandError
from django.urls import reverse

from metrology.errors import BadInput
from metrology.reports import services
from metrology.rigs.models import Rig


def find_rig(spec: str, user: str | None = None) -> Rig:
    rigs = Rig.objects.select_related("owner")
    if user:
        rigs = rigs.filter(owner__username=user)
    if spec.isdigit() and (rig := rigs.filter(pk=int(spec)).first()):
        return rig
    named = list(rigs.filter(name=spec))
    if not named:
        raise CommandError(f"no rig with id or name {spec!r}" + (f" owned by {user!r}" if user else ""))
    if len(named) > 1:
        ids = ", ".join(str(rig.pk) for rig in named)
        raise CommandError(f"{len(named)} rigs are named {spec!r} (ids {ids}); give the id or --user")
    return named[0]


class Command(BaseCommand):
    help = "Produce (or schedule) a characterization report of a rig and print where it is stored."

    def add_arguments(self, parser) -> None:
        parser.add_argument("rig", help="The rig's id or name")
        parser.add_argument("--user", help="Owner of the rig (to tell rigs with the same name apart)")
        parser.add_argument(
            "--source",
            choices=services.SOURCES,
            default="auto",
            help="virtual_stage simulates the stage series, uploaded_series takes the newest uploaded one; "
            "auto (default) takes an uploaded series when there is one",
        )
        parser.add_argument("--z-start", type=float, help="Virtual stage: first Z_in, mm (default 0)")
        parser.add_argument("--z-stop", type=float, help="Virtual stage: last Z_in, mm (default 80)")
        parser.add_argument("--z-step", type=float, help="Virtual stage: step, mm (default 8)")
        parser.add_argument("--repeats", type=int, help="Virtual stage: captures per position (default 2)")
        parser.add_argument("--noise-grey", type=float, help="Virtual stage: camera noise, grey levels (default 1.5)")
        parser.add_argument("--seed", type=int, help="Virtual stage: noise seed (default: from the report id)")
        parser.add_argument("--timeout", type=float, default=1800.0, help="Seconds to wait for the report")
        group = parser.add_mutually_exclusive_group()
        group.add_argument("--schedule-every", type=int, metavar="SECONDS", help="Schedule instead: every N seconds")
        group.add_argument("--schedule-crontab", metavar="CRON", help='Schedule instead: crontab, e.g. "0 6 * * *"')
        group.add_argument("--unschedule", action="store_true", help="Remove the rig's report schedule")

    def handle(self, *args, **opts) -> None:
        rig = find_rig(opts["rig"], opts.get("user"))
        names = {
            "z_start": "z_start_mm",
            "z_stop": "z_stop_mm",
            "z_step": "z_step_mm",
            "repeats": "repeats",
            "noise_grey": "noise_grey",
            "seed": "seed",
        }
        options = {key: opts[name] for name, key in names.items() if opts.get(name) is not None}
        try:
            if opts["unschedule"]:
                removed = services.unschedule_report(rig)
                self.stdout.write(f"rig {rig.pk}: schedule removed" if removed else f"rig {rig.pk}: no schedule")
                return
            if opts["schedule_every"] is not None or opts["schedule_crontab"]:
                task = services.schedule_report(
                    rig,
                    every_s=opts["schedule_every"],
                    crontab=opts["schedule_crontab"],
                    source=opts["source"],
                    options=options,
                )
                from metrology.reports.selectors import next_run_at, when_text

                upcoming = next_run_at(task)
                when = f"{upcoming:%Y-%m-%d %H:%M %Z}" if upcoming else "never (disabled)"
                self.stdout.write(
                    f"rig {rig.pk}: scheduled {when_text(task)} (periodic task {task.pk}), next run {when}; "
                    "it fires where celery beat and a worker run"
                )
                return
            report = services.run_characterization_report(
                rig, source=opts["source"], options=options, timeout_s=opts["timeout"]
            )
        except BadInput as exc:
            raise CommandError(str(exc)) from None
        job = report.job
        if job.status != job.Status.DONE:
            raise CommandError(f"report {report.pk} {job.status}: {job.error or 'not finished'}")
        self.say_summary(report)

    def say_summary(self, report) -> None:
        where = f"{report.html.name} in the media storage (page: /reports/{report.pk}/report.html)"
        overall = report.summary.get("overall", {})

        def um(key: str) -> str:
            value = overall.get(key)
            return "n/a" if value is None else f"{1000 * value:.1f} µm"

        self.stdout.write(f"report {report.pk} of rig {report.rig_id} ({report.get_source_display().lower()})")
        self.stdout.write(f"html: {where}")
        self.stdout.write(f"page: {reverse('reports:detail', args=[report.pk])}")
        pct = overall.get("error_pct_fs")
        self.stdout.write(
            f"mean error {um('mean_error_mm')}, sigma {um('std_error_mm')}, rms {um('rms_error_mm')}, "
            f"{'n/a' if pct is None else f'{pct:.4f}'} % of FS {overall.get('full_scale_mm')} mm, "
            f"max |slope - 1| {overall.get('max_abs_slope_deviation')}"
        )
        drift = report.drift
        if not drift.get("previous"):
            self.stdout.write("drift: first report of this rig (baseline)")
        else:
            moved = [item["label"] for item in drift.get("items", []) if item.get("beyond")]
            self.stdout.write(
                f"drift since report {drift['previous']}: "
                + (f"{len(moved)} beyond tolerance: {'; '.join(moved)}" if moved else "all within tolerance")
            )
