from django.apps import AppConfig


class CalibrationsConfig(AppConfig):
    name = "metrology.calibrations"
    label = "calibrations"
