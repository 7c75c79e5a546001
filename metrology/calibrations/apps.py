from django.apps import AppConfig


class CalibrationsConfig(AppConfig):
    name = "metrology.calibrations"
    label = "calibrations"

    def ready(self) -> None:
        from metrology.calibrations.procam_services import run_procam_calibration
        from metrology.calibrations.services import run_calibration
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.CALIBRATION, run_calibration)
        register_handler(Job.Kind.PROCAM_CALIBRATION, run_procam_calibration)
