from django.apps import AppConfig


class ReportsConfig(AppConfig):
    name = "metrology.reports"
    label = "reports"
    verbose_name = "Characterization reports"
