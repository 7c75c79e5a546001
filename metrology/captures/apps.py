from django.apps import AppConfig


class CapturesConfig(AppConfig):
    name = "metrology.captures"
    label = "captures"
