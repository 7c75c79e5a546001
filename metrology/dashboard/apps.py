from django.apps import AppConfig


class DashboardConfig(AppConfig):
    name = "metrology.dashboard"
    label = "dashboard"
    verbose_name = "Dashboard"
