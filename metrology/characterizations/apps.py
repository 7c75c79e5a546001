from django.apps import AppConfig


class CharacterizationsConfig(AppConfig):
    name = "metrology.characterizations"
    label = "characterizations"
