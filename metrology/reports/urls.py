"""Report pages and downloads."""

urlpatterns: list = []
