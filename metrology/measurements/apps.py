from django.apps import AppConfig


class MeasurementsConfig(AppConfig):
    name = "metrology.measurements"
    label = "measurements"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job
        from metrology.measurements.services import run_measurement

        register_handler(Job.Kind.MEASUREMENT, run_measurement)
