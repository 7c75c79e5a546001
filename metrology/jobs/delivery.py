"""Per-job delivery markers: which queued jobs still have a message in the broker.

A job's message is sent once (:func:`metrology.jobs.services.enqueue_job`); the sweep sends it again
only when it was really lost (a send that failed after commit, Redis restarted without its data, a
worker that died holding it unstarted), never merely because the job waits behind a backlog. To
tell these apart, every send first writes a marker key beside the broker's queues, in the same
Redis: ``gcps:<queue>:message:<job id>``, expiring after :data:`MARKER_TTL_S`.

- ``sent``: written *before* the message is published (removed when publishing fails), so a
  worker that receives the message at once cannot overwrite it before it was written. The message
  waits in the queue.
- ``reserved:<worker>``: written by the worker that receives the message (Celery's
  ``task_received``, in :mod:`metrology.jobs.tasks`); it may hold it unstarted behind its running
  job (prefetch). The message still counts as waiting while that worker is alive: every worker
  refreshes a liveness key ``gcps:<queue>:worker:<worker>`` at each sweep (:func:`keep_alive`),
  expiring after :func:`liveness_ttl_s`. A worker that died leaves its reserved jobs queued and
  without a live owner: they are sent again.
- Redis restarted without its data loses the markers with the messages: those jobs are sent again.

Brokers other than Redis, and the embedded default, have no markers: :func:`waiting_in_broker`
answers ``None`` and the sweep resends every job queued longer than ``GCPS_JOB_RESEND_SECONDS``.
"""

from __future__ import annotations

import functools
import logging
import os
import socket
from collections.abc import Iterable

from django.conf import settings

logger = logging.getLogger(__name__)

MARKER_TTL_S = 7 * 24 * 3600
"""Lifetime of a marker, seconds: a job still waiting after a week is sent again (harmless: a
job runs once whatever the number of its messages)."""


@functools.cache
def _client(url: str):  # -> redis.Redis | None
    if not url.startswith(("redis://", "rediss://")):
        return None
    import redis

    return redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2)


def client():  # -> redis.Redis | None
    """A Redis client of the broker's server; ``None`` without a Redis broker (markers unsupported)."""
    if settings.CELERY_TASK_ALWAYS_EAGER:
        return None
    return _client(settings.CELERY_BROKER_URL)


SENT = "sent"
RESERVED = "reserved:"


def marker_key(job_id: int) -> str:
    return f"gcps:{settings.CELERY_TASK_DEFAULT_QUEUE}:message:{int(job_id)}"


def worker_id() -> str:
    """This process's name in the markers (a worker's main process: it receives the messages and
    runs the sweep)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def liveness_key(worker: str) -> str:
    return f"gcps:{settings.CELERY_TASK_DEFAULT_QUEUE}:worker:{worker}"


def liveness_ttl_s() -> int:
    """How long a worker counts as alive after its last sweep: three sweep periods (and at least
    ``GCPS_JOB_STALE_SECONDS``, the time after which its running jobs are taken over)."""
    return max(3 * settings.GCPS_JOB_SWEEP_SECONDS + 2, settings.GCPS_JOB_STALE_SECONDS)


def _write(what: str, keys: dict[str, tuple[str, int] | None]) -> None:
    """Set (value, seconds to live) or delete (``None``) each key; best effort: a Redis error is logged."""
    import redis

    redis_client = client()
    if redis_client is None:
        return
    try:
        for key, value in keys.items():
            if value is None:
                redis_client.delete(key)
            else:
                redis_client.set(key, value[0], ex=value[1])
    except redis.RedisError:  # a send fails too, or the sweep sends the job again: never worse than no marker
        logger.warning("could not write %s", what, exc_info=True)


def keep_alive() -> None:
    """Refresh this worker's liveness key (called at each of its sweeps)."""
    _write("this worker's liveness key", {liveness_key(worker_id()): ("1", liveness_ttl_s())})


def mark_sent(job_id: int) -> None:
    """Record that a message for ``job_id`` is about to wait in the broker."""
    _write(f"the delivery marker of job {job_id}", {marker_key(job_id): (SENT, MARKER_TTL_S)})


def mark_unsent(job_id: int) -> None:
    """The send failed: no message waits."""
    _write(f"the delivery marker of job {job_id}", {marker_key(job_id): None})


def mark_received(job_id: int) -> None:
    """This worker holds the job's message (received, maybe not started yet)."""
    _write(
        f"the delivery marker of job {job_id}",
        {
            marker_key(job_id): (RESERVED + worker_id(), MARKER_TTL_S),
            liveness_key(worker_id()): ("1", liveness_ttl_s()),
        },
    )


def waiting_in_broker(job_ids: Iterable[int]) -> set[int] | None:
    """The ids among ``job_ids`` whose message waits in the broker or in a live worker's hands;
    ``None`` when that cannot be told (no Redis broker, or Redis unreachable): then every job is
    taken to need its message again."""
    import redis

    redis_client = client()
    if redis_client is None:
        return None
    ids = list(job_ids)
    markers: dict[int, str] = {}
    try:
        for start in range(0, len(ids), 500):
            chunk = ids[start : start + 500]
            values = redis_client.mget([marker_key(job_id) for job_id in chunk])
            markers.update((job_id, value.decode()) for job_id, value in zip(chunk, values, strict=True) if value)
        owners = sorted({value.removeprefix(RESERVED) for value in markers.values() if value.startswith(RESERVED)})
        alive = (
            {
                owner
                for owner, value in zip(owners, redis_client.mget([liveness_key(o) for o in owners]), strict=True)
                if value
            }
            if owners
            else set()
        )
    except redis.RedisError:
        logger.warning("could not read the delivery markers", exc_info=True)
        return None
    return {
        job_id
        for job_id, value in markers.items()
        if value == SENT or (value.startswith(RESERVED) and value.removeprefix(RESERVED) in alive)
    }
