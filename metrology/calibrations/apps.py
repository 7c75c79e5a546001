from django.apps import AppConfig


class CalibrationsConfig(AppConfig):
    name = "metrology.calibrations"
    label = "calibrations"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.CALIBRATION, "metrology.calibrations.services.run_calibration")
        register_handler(Job.Kind.PROCAM_CALIBRATION, "metrology.calibrations.procam_services.run_procam_calibration")
