from django.apps import AppConfig


class JobsConfig(AppConfig):
    name = "metrology.jobs"
    label = "jobs"
    verbose_name = "Background jobs"

    def ready(self) -> None:
        # The Celery app (configured from these settings) becomes the current app of every process
        # that runs Django, so the web process sends run_job to the broker the workers read.
        import workers.celery  # noqa: F401
