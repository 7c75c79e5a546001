"""The documented web server (gunicorn + uvicorn worker on ``metrology.asgi``) with projector long-polls waiting.

One worker process, 20 long-polls waiting on it: another user's requests are answered at once, the
long-polls answer as soon as the state changes, and a client that goes away ends its wait (its
Redis subscription is dropped). Real PostgreSQL, real Redis, real server.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import psycopg
import pytest
import redis
import requests

from tests.app.integration.harness import (
    OTHER_TEMPLATE_USER,
    PG_ADMIN_URL,
    TEMPLATE_USER,
    Stack,
    migrated_stack,
    template_user_token,
)
from tests.app.integration.helpers import RIG

pytestmark = pytest.mark.integration

LONG_POLLS = 20


@pytest.fixture(scope="module")
def asgi_stack(tmp_path_factory) -> Iterator[Stack]:
    """The server, started once for the module's tests (its start costs about 0.8 s of CPU); each
    test makes its own rigs and waits on their channels."""
    folder = tmp_path_factory.mktemp("asgi")
    (folder / "media").mkdir()
    with migrated_stack(folder, folder / "media") as stack:
        stack.start_asgi(workers=1)
        yield stack


def session_of(stack: Stack, *, other_user: bool = False) -> requests.Session:
    """A session of the user the stack's database was copied with, or (``other_user``) of the
    template's other user (:data:`harness.OTHER_TEMPLATE_USER`)."""
    key = template_user_token(OTHER_TEMPLATE_USER if other_user else TEMPLATE_USER)
    session = requests.Session()
    session.headers["Authorization"] = f"Token {key}"
    return session


def database_connections(stack: Stack) -> int:
    name = stack.env["DATABASE_URL"].rsplit("/", 1)[1]
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        row = conn.execute("SELECT count(*) FROM pg_stat_activity WHERE datname = %s", (name,)).fetchone()
    assert row is not None
    return int(row[0])


def test_long_polls_leave_other_requests_unaffected_and_answer_on_change(asgi_stack):
    base = asgi_stack.base_url
    owner, other = session_of(asgi_stack), session_of(asgi_stack, other_user=True)
    rig_id = owner.post(f"{base}/api/rigs/", json=RIG).json()["id"]
    assert other.post(f"{base}/api/rigs/", json={**RIG, "name": "other's"}).status_code == 201
    agent = owner.post(f"{base}/api/rigs/{rig_id}/agent/register/", json={"camera": "virtual", "name": "bench"})
    assert agent.status_code == 201, agent.text
    session = agent.json()["session"]
    seq = owner.get(f"{base}/api/rigs/{rig_id}/projector/").json()["seq"]

    answers: list[tuple[float, dict]] = []
    lock = threading.Lock()

    def long_poll() -> None:
        with requests.Session() as client:
            client.headers.update(owner.headers)
            response = client.get(f"{base}/api/rigs/{rig_id}/projector/?after={seq}&wait=20", timeout=40)
            assert response.status_code == 200, response.text
            with lock:
                answers.append((time.monotonic(), response.json()))

    threads = [threading.Thread(target=long_poll) for _ in range(LONG_POLLS)]
    for thread in threads:
        thread.start()
    time.sleep(2.0)  # every long-poll has reached the server and waits
    assert answers == []

    latencies = []
    for _ in range(10):
        started = time.monotonic()
        response = other.get(f"{base}/api/rigs/", timeout=10)
        latencies.append(time.monotonic() - started)
        assert response.status_code == 200 and [rig["name"] for rig in response.json()] == ["other's"]
    assert max(latencies) < 1.0, latencies
    assert answers == [], "the long-polls must still be waiting"
    assert database_connections(asgi_stack) <= 3  # waiting holds no connection (a thread each would hold 20)

    shown_at = time.monotonic()
    shown = owner.post(f"{base}/api/rigs/{rig_id}/projector/", json={"session": session, "kind": "white"})
    assert shown.status_code == 200, shown.text
    for thread in threads:
        thread.join(timeout=30)
    assert len(answers) == LONG_POLLS
    assert all(body["seq"] == seq + 1 and body["kind"] == "white" for _, body in answers)
    delays = sorted(moment - shown_at for moment, _ in answers)
    assert delays[-1] < 1.0, delays  # notified, not the 20 s timeout (nor the 1 s re-read)


def test_a_client_that_disconnects_ends_its_wait(asgi_stack):
    base = asgi_stack.base_url
    owner = session_of(asgi_stack)
    rig_id = owner.post(f"{base}/api/rigs/", json=RIG).json()["id"]
    seq = owner.get(f"{base}/api/rigs/{rig_id}/projector/").json()["seq"]
    broker = redis.Redis.from_url(asgi_stack.env["REDIS_URL"])
    channel = f"{asgi_stack.env['GCPS_CACHE_KEY_PREFIX']}:projector:{rig_id}"

    def subscribers() -> int:
        return dict(broker.pubsub_numsub(channel)).get(channel.encode(), 0)

    def impatient() -> None:
        with requests.Session() as client, pytest.raises(requests.ReadTimeout):
            client.headers.update(owner.headers)
            client.get(f"{base}/api/rigs/{rig_id}/projector/?after={seq}&wait=25", timeout=2.0)

    threads = [threading.Thread(target=impatient) for _ in range(5)]
    for thread in threads:
        thread.start()
    time.sleep(1.0)
    assert subscribers() == 5  # waiting on the event loop, subscribed to the rig's channel
    for thread in threads:
        thread.join(timeout=10)
    deadline = time.monotonic() + 5
    while subscribers() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert subscribers() == 0  # the clients left after 2 s: their waits ended, not after 25 s
