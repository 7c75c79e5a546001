from django.apps import AppConfig


class ReportsConfig(AppConfig):
    name = "metrology.reports"
    label = "reports"
    verbose_name = "Characterization reports"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.REPORT, "metrology.reports.services.run_report")
