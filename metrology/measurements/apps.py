from django.apps import AppConfig


class MeasurementsConfig(AppConfig):
    name = "metrology.measurements"
    label = "measurements"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.MEASUREMENT, "metrology.measurements.services.run_measurement")
        register_handler(Job.Kind.DERIVED_FILE, "metrology.measurements.services.run_derived_file")
