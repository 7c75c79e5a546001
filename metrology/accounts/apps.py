from django.apps import AppConfig


class AccountsConfig(AppConfig):
    name = "metrology.accounts"
    label = "accounts"
