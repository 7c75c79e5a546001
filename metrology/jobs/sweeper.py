"""The job sweep run by the workers themselves, so that recovery never waits on beat.

Every worker process (its main process, whatever the pool) runs :func:`metrology.jobs.services.sweep_jobs`
every ``GCPS_JOB_SWEEP_SECONDS`` (plus up to 20 % random delay, so that workers started together
spread out) on a daemon thread. The sweep is safe to run from several workers at once: every change
it makes is made under a row lock and re-checked.
"""

from __future__ import annotations

import logging
import random
import threading

from django.conf import settings
from django.db import close_old_connections, connection

logger = logging.getLogger(__name__)


class PeriodicSweep(threading.Thread):
    """A daemon thread calling ``sweep_jobs()`` every ``interval_s`` seconds until :meth:`stop`."""

    def __init__(self, interval_s: float | None = None) -> None:
        super().__init__(name="gcps-job-sweep", daemon=True)
        self.interval_s = float(interval_s if interval_s is not None else settings.GCPS_JOB_SWEEP_SECONDS)
        self.stop_event = threading.Event()
        self.runs = 0

    def run(self) -> None:
        from metrology.jobs.delivery import keep_alive
        from metrology.jobs.services import sweep_jobs

        keep_alive()

        try:
            while not self.stop_event.wait(self.interval_s * (1.0 + 0.2 * random.random())):
                try:
                    keep_alive()  # the messages this worker holds unstarted count as waiting (jobs/delivery.py)
                    close_old_connections()  # drop one past its age or broken, as a request would
                    sweep_jobs()
                    self.runs += 1
                except Exception:  # the database or broker may be away for a while: try again next time
                    logger.warning("job sweep failed; trying again in %.0f s", self.interval_s, exc_info=True)
                    connection.close()
        finally:
            connection.close()

    def stop(self) -> None:
        self.stop_event.set()
        self.join(timeout=10)
