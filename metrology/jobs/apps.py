from django.apps import AppConfig


class JobsConfig(AppConfig):
    name = "metrology.jobs"
    label = "jobs"
    verbose_name = "Background jobs"
