"""The Redis broker transport of the Celery app: kombu's, made to survive a Redis restart.

When the connection to Redis drops while the worker holds unacknowledged messages (a job being
run with late acknowledgement, or a retry waiting for its countdown), the worker closes the
channel, and kombu's channel tries to put those messages back on the queue *after* it has dropped
its connection pool and detached from the connection: ``AttributeError: 'NoneType' object has no
attribute 'hostname'``. That error is not a connection error, so the worker stopped for good
(kombu 5.7, reproduced by ``tests/app/integration/test_faults.py``). Here that one case is caught:
the messages stay in Redis's unacked set, which any worker restores after the visibility timeout
(or which a Redis restart without persistence has emptied anyway), and the job rows are recovered
by the job sweep (``metrology/jobs/services.py``), so nothing is lost and the worker reconnects.

Selected by ``CELERY_BROKER_TRANSPORT`` in settings for ``redis://`` and ``rediss://`` brokers.
"""

from __future__ import annotations

import logging

from kombu.transport import redis as kombu_redis

logger = logging.getLogger(__name__)


class QoS(kombu_redis.QoS):
    def restore_unacked(self, client: object = None) -> None:
        try:
            super().restore_unacked(client)
        except AttributeError:
            transport = self.channel.connection
            if transport is not None and getattr(transport, "client", None) is not None:
                raise  # not the closed-connection case: a real bug, let it show
            logger.warning(
                "broker connection closed before %d unacknowledged message(s) could be requeued; "
                "Redis keeps them for redelivery after the visibility timeout and the job sweep "
                "recovers their jobs",
                len(self._delivered),
            )
            self._delivered.clear()


class Channel(kombu_redis.Channel):
    QoS = QoS


class Transport(kombu_redis.Transport):
    Channel = Channel
