from django.apps import AppConfig


class ReportsConfig(AppConfig):
    name = "metrology.reports"
    label = "reports"
    verbose_name = "Characterization reports"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job
        from metrology.reports.services import run_report

        register_handler(Job.Kind.REPORT, run_report)
