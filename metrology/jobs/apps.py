from django.apps import AppConfig


class JobsConfig(AppConfig):
    name = "metrology.jobs"
    label = "jobs"
    verbose_name = "Background jobs"

    def ready(self) -> None:
        from celery.signals import worker_init

        # The Celery app (configured from these settings) becomes the current app of every process
        # that runs Django, so the web process sends run_job to the broker the workers read.
        import workers.celery  # noqa: F401
        from metrology.jobs.handlers import preload_job_code

        # The handlers are registered by path (django.setup() imports none of the services and
        # pipelines): a worker imports them, and what they compute with, as it starts.
        worker_init.connect(preload_job_code, dispatch_uid="gcps-preload-job-code")
