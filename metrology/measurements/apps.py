from django.apps import AppConfig


class MeasurementsConfig(AppConfig):
    name = "metrology.measurements"
    label = "measurements"
