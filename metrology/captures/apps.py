from django.apps import AppConfig


class CapturesConfig(AppConfig):
    name = "metrology.captures"
    label = "captures"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.SIMULATE_CAPTURE, "metrology.captures.services.run_simulate_capture")
