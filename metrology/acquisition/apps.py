from django.apps import AppConfig


class AcquisitionConfig(AppConfig):
    name = "metrology.acquisition"
    label = "acquisition"
    verbose_name = "Acquisition"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler, register_sweep
        from metrology.jobs.models import Job

        register_handler(Job.Kind.ACQUIRE_CAPTURE, "metrology.acquisition.services.run_acquisition_job")
        register_sweep("metrology.acquisition.services.sweep_acquisitions")
