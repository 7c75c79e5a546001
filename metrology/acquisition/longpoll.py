"""The projector state's long-poll, waited for without a thread, a web worker or a database connection.

``GET /api/rigs/{id}/projector/?after=N`` (the projector page: "tell me when there is a pattern
newer than N") and ``?shown=N`` (the agent: "tell me when the page has painted pattern N") wait up
to ``wait`` seconds (at most :data:`MAX_WAIT_S`). Under the ASGI server (docs/operations.md, "Web
server") the wait is a coroutine on the worker's event loop: any number of long-polls hold no
thread and no database connection, so they leave every other request unaffected.

How a waiter learns of a change: :func:`notify_changed`, called by the two writers of the state
(``services.show_on_projector`` and ``services.confirm_shown``), publishes the rig's id on the Redis
channel ``{GCPS_CACHE_KEY_PREFIX}:projector:{rig_id}`` once the write has committed; a waiter subscribed to it reads
the state again at once. It also reads it every :data:`RECHECK_WITH_REDIS_S` seconds in case a
message was missed (Redis restarted, a write made elsewhere). Without Redis (the embedded default)
or when the subscription fails, it reads the state every :data:`POLL_S` seconds instead, each read
in a short ``sync_to_async`` call that closes its connection afterwards (PostgreSQL). A client that disconnects
ends its wait: Django cancels the view's task (``asyncio.CancelledError``) and the subscription is
closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

from asgiref.sync import sync_to_async
from django.conf import settings
from django.db import connections, transaction

from metrology.acquisition.models import ProjectorState

if TYPE_CHECKING:
    import redis
    import redis.asyncio

# redis (and with it redis.asyncio: 0.1-0.15 s of CPU) is imported by the functions that use it:
# the web server's URLconf imports this module at every start

logger = logging.getLogger(__name__)

MAX_WAIT_S = 25.0
"""Longest wait of one long-poll, seconds (clients ask again)."""
POLL_S = 0.05
"""Interval between reads of the state when no Redis notifications are available, seconds."""
RECHECK_WITH_REDIS_S = 1.0
"""Interval between reads of the state while subscribed to the notifications, seconds."""


def channel(rig_id: int) -> str:
    """The Redis pub/sub channel on which changes of a rig's projector state are announced.

    Prefixed like the cache's keys (``GCPS_CACHE_KEY_PREFIX``), so instances sharing a Redis do not
    wake each other's waiters.
    """
    prefix = settings.CACHES["default"].get("KEY_PREFIX") or "gcps"
    return f"{prefix}:projector:{rig_id}"


@functools.cache
def _publisher(url: str) -> redis.Redis:
    import redis

    return redis.Redis.from_url(url, socket_timeout=2.0, socket_connect_timeout=2.0)


def notify_changed(rig_id: int) -> None:
    """Announce, once the current transaction commits, that rig ``rig_id``'s projector state changed.

    Without ``REDIS_URL`` nothing is sent (waiters poll). A Redis error is logged, never raised: the
    waiters' periodic re-read still sees the change within :data:`RECHECK_WITH_REDIS_S`.
    """
    url = settings.REDIS_URL
    if not url:
        return

    def publish() -> None:
        import redis

        try:
            _publisher(url).publish(channel(rig_id), b"1")
        except (redis.RedisError, OSError) as exc:
            logger.warning("projector change of rig %s not announced: %s", rig_id, exc)

    transaction.on_commit(publish)


@dataclass(frozen=True)
class LongPoll:
    """What a long-poll waits for: ``seq > seq_above`` or ``shown_seq >= shown_at_least``, until ``deadline``.

    ``deadline`` is a ``time.monotonic()`` instant.
    """

    rig_id: int
    seq_above: int | None
    shown_at_least: int | None
    deadline: float

    @classmethod
    def start(cls, rig_id: int, *, seq_above: int | None, shown_at_least: int | None, timeout_s: float) -> LongPoll:
        """A long-poll starting now, its wait clipped to ``[0, MAX_WAIT_S]`` seconds."""
        timeout = max(0.0, min(timeout_s, MAX_WAIT_S))
        return cls(rig_id, seq_above, shown_at_least, time.monotonic() + timeout)

    def reached(self, state: ProjectorState) -> bool:
        """Whether ``state`` answers the long-poll (without waiting)."""
        if self.seq_above is not None and state.seq > self.seq_above:
            return True
        return self.shown_at_least is not None and state.shown_seq >= self.shown_at_least

    def remaining(self) -> float:
        """Seconds left until the deadline (0 when past)."""
        return max(0.0, self.deadline - time.monotonic())


def release_connection() -> None:
    """Close this thread's database connection, so that a waiting long-poll holds none.

    Not inside a transaction (the tests' one), and not on SQLite (the embedded default: one
    process under ``runserver``, no server-side connection limit to protect): there the request's
    connection is kept, as the synchronous long-poll kept it.
    """
    connection = connections["default"]
    if not connection.in_atomic_block and connection.vendor != "sqlite":
        connection.close()


def _read(rig_id: int) -> ProjectorState | None:
    try:
        return ProjectorState.objects.filter(rig_id=rig_id).first()
    finally:
        release_connection()


@contextlib.asynccontextmanager
async def _subscription(rig_id: int) -> AsyncIterator[redis.asyncio.client.PubSub | None]:
    """A subscription to the rig's channel, or None without Redis or when Redis cannot be reached."""
    url = settings.REDIS_URL
    if not url:
        yield None
        return
    import redis.asyncio

    client = redis.asyncio.Redis.from_url(url, socket_timeout=5.0, socket_connect_timeout=2.0)
    pubsub = client.pubsub(ignore_subscribe_messages=True)
    try:
        try:
            await pubsub.subscribe(channel(rig_id))
        except (redis.RedisError, OSError) as exc:
            logger.warning("projector long-poll of rig %s polls the database: %s", rig_id, exc)
            yield None
        else:
            yield pubsub
    finally:
        with contextlib.suppress(Exception):
            await pubsub.aclose()
        with contextlib.suppress(Exception):
            await client.aclose()


async def wait(poll: LongPoll, state: ProjectorState) -> ProjectorState:
    """The projector state once ``poll`` is reached, or at its deadline; ``state`` is the one last read.

    A coroutine: it holds no thread and no database connection between reads.
    """
    import redis

    async with _subscription(poll.rig_id) as pubsub:
        while not poll.reached(state):
            remaining = poll.remaining()
            if remaining <= 0:
                break
            if pubsub is None:
                await asyncio.sleep(min(remaining, POLL_S))
            else:
                try:
                    await pubsub.get_message(timeout=min(remaining, RECHECK_WITH_REDIS_S))
                except (redis.RedisError, OSError) as exc:
                    logger.warning("projector long-poll of rig %s lost Redis, polls the database: %s", poll.rig_id, exc)
                    pubsub = None
            current = await sync_to_async(_read)(poll.rig_id)
            if current is None:  # the rig was deleted meanwhile
                break
            state = current
    return state
