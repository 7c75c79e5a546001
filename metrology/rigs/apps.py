from django.apps import AppConfig


class RigsConfig(AppConfig):
    name = "metrology.rigs"
    label = "rigs"
