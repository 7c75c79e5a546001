from django.apps import AppConfig


class CharacterizationsConfig(AppConfig):
    name = "metrology.characterizations"
    label = "characterizations"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job

        register_handler(Job.Kind.CHARACTERIZATION, "metrology.characterizations.services.run_characterization")
