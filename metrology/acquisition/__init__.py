"""Acquisition from a real rig (issue 14): projector page, capture agents, acquisition requests.

The Django side (models, services, api, views) lives here; :mod:`metrology.acquisition.agent`
is the agent side (camera backends, frame checks, sequencing, the HTTP client) and imports no
Django, so ``gcps agent`` and ``gcps capture`` run on a rig computer without the server's settings.
"""
