"""Browser pages (server-rendered)."""

urlpatterns: list = []
