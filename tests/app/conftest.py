"""Fixtures for the application tests: users with tokens, API clients, rigs and stored captures made
through the API (the media root is tests/conftest.py's)."""

from __future__ import annotations

import pytest
from rest_framework.test import APIClient

from metrology.accounts.services import create_user_with_token
from metrology.core.geometry.crossed_axes import Rig
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload
from tests.pinhole_stacks import RIG as PINHOLE_RIG


@pytest.fixture
def user_and_token(db):
    return create_user_with_token(username="alice")


@pytest.fixture
def api(user_and_token) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {user_and_token[1]}")
    client.user = user_and_token[0]
    return client


@pytest.fixture
def other_api(db) -> APIClient:
    user, key = create_user_with_token(username="bob")
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    client.user = user
    return client


@pytest.fixture
def rig(api) -> dict:
    response = api.post("/api/rigs/", {**SMALL_RIG, "name": "bench"}, format="json")
    assert response.status_code == 201, response.content
    return response.json()


@pytest.fixture
def pinhole_rig(api) -> dict:
    response = api.post("/api/rigs/", {**PINHOLE_RIG.to_dict(), "name": "pinhole bench"}, format="json")
    assert response.status_code == 201, response.content
    return response.json()


@pytest.fixture
def captures(api, rig) -> tuple[int, int]:
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, block_heights(), bit_depth=16)), "object")
    return reference, obj
