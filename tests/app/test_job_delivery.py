"""Delivery markers (issue 23 item 6, no re-send storm): the sweep sends a queued job again only when
its message is lost, and sends it to the head of the queue. Markers live in a real Redis (the
shared test server, under a queue name of this test's own)."""

from __future__ import annotations

import secrets
from datetime import timedelta

import pytest
import redis
from django.utils import timezone

from metrology.jobs import delivery, services
from metrology.jobs.models import Job
from tests.app.integration.harness import REDIS_URL

pytestmark = pytest.mark.integration


@pytest.fixture
def markers(settings):
    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2).ping()
    except redis.RedisError as exc:
        pytest.skip(f"Redis at {REDIS_URL}: {exc}")
    settings.CELERY_TASK_ALWAYS_EAGER = False
    settings.CELERY_BROKER_URL = REDIS_URL
    settings.CELERY_TASK_DEFAULT_QUEUE = f"gcps-test-{secrets.token_hex(4)}"
    client = delivery.client()
    assert client is not None
    yield client
    for key in client.scan_iter(f"gcps:{settings.CELERY_TASK_DEFAULT_QUEUE}:*"):
        client.delete(key)


def test_a_marker_says_whether_a_message_waits(markers):
    delivery.mark_sent(1)
    delivery.mark_sent(2)
    delivery.mark_unsent(2)  # its send failed
    assert delivery.waiting_in_broker([1, 2, 3]) == {1}
    assert 0 < markers.ttl(delivery.marker_key(1)) <= delivery.MARKER_TTL_S


def test_a_message_held_by_a_worker_waits_while_the_worker_lives(markers):
    delivery.mark_sent(7)
    delivery.mark_received(7)  # this process is the worker holding it
    assert markers.get(delivery.marker_key(7)) == f"reserved:{delivery.worker_id()}".encode()
    assert delivery.waiting_in_broker([7]) == {7}
    markers.delete(delivery.liveness_key(delivery.worker_id()))  # the worker died: its key expired
    assert delivery.waiting_in_broker([7]) == set()
    delivery.keep_alive()  # alive again (its sweep ran)
    assert delivery.waiting_in_broker([7]) == {7}


def test_without_a_redis_broker_nothing_can_be_told(settings):
    settings.CELERY_TASK_ALWAYS_EAGER = True
    assert delivery.waiting_in_broker([1]) is None


def test_the_sweep_resends_only_the_jobs_whose_message_is_lost_and_at_the_head(
    markers, user_and_token, monkeypatch, django_capture_on_commit_callbacks
):
    sent: list[tuple[int, bool]] = []
    monkeypatch.setattr(services, "check_broker", lambda: None)
    monkeypatch.setattr(services, "_send", lambda job_id, recovered=False: sent.append((job_id, recovered)))
    long_ago = timezone.now() - timedelta(seconds=3600)
    jobs = [services.create_job(owner=user_and_token[0], kind="measurement", parameters={}) for _ in range(5)]
    Job.objects.filter(pk__in=[job.pk for job in jobs]).update(enqueued_at=long_ago)
    waiting, held, lost, held_by_the_dead, failed_send = jobs
    delivery.mark_sent(waiting.pk)
    delivery.mark_received(held.pk)
    markers.set(delivery.marker_key(held_by_the_dead.pk), "reserved:gone-host:1")
    delivery.mark_sent(failed_send.pk)
    delivery.mark_unsent(failed_send.pk)
    with django_capture_on_commit_callbacks(execute=True):
        counts = services.resend_unclaimed_jobs()
    assert counts == {"resent": 3, "waiting": 2}
    assert sorted(sent) == sorted((job.pk, True) for job in (lost, held_by_the_dead, failed_send))
    # a backlog is not sent again at every sweep: the resent jobs' own markers say they wait now
    # (the patched send wrote none, so write them as the real one does)
    for job_id, _ in sent:
        delivery.mark_sent(job_id)
    Job.objects.filter(pk__in=[job.pk for job in jobs]).update(enqueued_at=long_ago)
    with django_capture_on_commit_callbacks(execute=True):
        assert services.resend_unclaimed_jobs() == {"resent": 0, "waiting": 5}
