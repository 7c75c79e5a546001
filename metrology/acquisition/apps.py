from django.apps import AppConfig


class AcquisitionConfig(AppConfig):
    name = "metrology.acquisition"
    label = "acquisition"
    verbose_name = "Acquisition"
