"""The Redis broker transport of the Celery app: kombu's, made to survive a Redis restart.

When the connection to Redis drops, the worker closes the channel: kombu's Redis channel drops its
connection pool and detaches from the connection (``channel.connection = None``). Two things can
still use that channel afterwards, and both then need a new pool, whose parameters kombu reads
from the detached transport (``channel.connection``, None once the channel is closed: ``AttributeError:
'NoneType' object has no attribute 'client'``) or from the closed connection (``transport.client``,
None once Celery has collected the lost connection: ``... no attribute 'hostname'``):

- **restore**: while closing, the channel puts the messages it holds unacknowledged (a job being
  run with late acknowledgement, a retry waiting for its countdown) back on the queue;
- **ack**: a job that was running in a pool process when the connection dropped finishes after
  the channel was closed, and the worker acknowledges its message on that channel.

An ``AttributeError`` is not one of the transport's connection errors, so it escaped Celery's
handling and the worker stopped for good (kombu 5.7.0 and Celery 5.7.0, the newest releases; no
setting avoids it: ``worker_cancel_long_running_tasks_on_connection_loss`` only cancels the
running jobs). Here a closed channel that is asked for a client raises :class:`ChannelClosed`, a
``redis.ConnectionError``: Celery then logs the failed acknowledgement ("Couldn't ack") and carries
on, and the restore is skipped with a warning. Nothing is lost: the message stays in Redis's
unacked set, which any worker restores after the visibility timeout (or which a Redis restart
without persistence has emptied anyway), and the job rows are recovered by the job sweep
(``metrology/jobs/services.py``); a message delivered again for a job already done is dropped.
``tests/app/integration/test_faults.py`` kills a private Redis at each point (ack, restore, countdown).

Selected by ``CELERY_BROKER_TRANSPORT`` in settings for ``redis://`` and ``rediss://`` brokers.
"""

from __future__ import annotations

import logging

import redis
from kombu.transport import redis as kombu_redis

logger = logging.getLogger(__name__)


class ChannelClosed(redis.ConnectionError):
    """A closed channel (its connection lost) was asked for a Redis client."""


class QoS(kombu_redis.QoS):
    def restore_unacked(self, client: object = None) -> None:
        try:
            super().restore_unacked(client)
        except ChannelClosed:
            logger.warning(
                "broker connection closed before %d unacknowledged message(s) could be requeued; "
                "Redis keeps them for redelivery after the visibility timeout and the job sweep "
                "recovers their jobs",
                len(self._delivered),
            )
            self._delivered.clear()


class Channel(kombu_redis.Channel):
    QoS = QoS

    def _connparams(self, asynchronous: bool = False) -> dict:
        if self.connection is None or self.connection.client is None:
            raise ChannelClosed("the broker channel was closed when its connection was lost")
        return super()._connparams(asynchronous=asynchronous)


class Transport(kombu_redis.Transport):
    Channel = Channel
