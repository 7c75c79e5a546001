"""The projector long-poll in-process (the embedded default: no Redis, the state read every 0.05 s):
it answers as soon as the page confirms a pattern, and at ``wait`` when nothing changes."""

from __future__ import annotations

import json
import threading
import time

import pytest
from django.test import Client

from metrology.acquisition import services
from tests.conftest import logged_in


@pytest.mark.django_db(transaction=True)
def test_long_poll_answers_when_the_page_confirms_and_at_the_wait_otherwise(alice, rig):
    seq = services.show_on_projector(rig, kind="white")
    agent, page = logged_in(alice), logged_in(alice)

    confirmed: list[float] = []

    def confirm() -> None:
        time.sleep(0.5)
        answer = page.post(
            f"/api/rigs/{rig.pk}/projector/shown/",
            json.dumps({"seq": seq, "kind": "white", "frame": -1}),
            content_type="application/json",
        )
        assert answer.status_code == 200
        confirmed.append(time.monotonic())

    confirming = threading.Thread(target=confirm)
    started = time.monotonic()
    confirming.start()
    state = agent.get(f"/api/rigs/{rig.pk}/projector/?shown={seq}&wait=10").json()
    answered = time.monotonic()
    confirming.join()
    assert state["shown_seq"] == seq and state["shown_kind"] == "white"
    assert answered - started > 0.4  # it waited for the confirmation ...
    assert answered - confirmed[0] < 1.0  # ... and answered at once, not at the 10 s wait

    started = time.monotonic()
    state = agent.get(f"/api/rigs/{rig.pk}/projector/?after={seq}&wait=0.6").json()
    assert 0.55 < time.monotonic() - started < 3.0
    assert state["seq"] == seq

    anonymous = Client().get(f"/api/rigs/{rig.pk}/projector/?after={seq}&wait=5")
    assert anonymous.status_code in (401, 403)  # the DRF checks run before any wait
