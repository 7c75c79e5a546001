"""docs/operations.md says what beat sends and what happens to a worker on a Redis outage
(issue 23 item 6): the beat entries it names are the Celery app's, and it does not promise that
workers always reconnect."""

from __future__ import annotations

from pathlib import Path

OPERATIONS = Path(__file__).resolve().parents[1] / "docs" / "operations.md"


def test_the_doc_names_every_beat_entry_of_the_app():
    from workers.celery import app

    text = OPERATIONS.read_text()
    assert "only for report schedules" not in text
    schedule = app.conf.beat_schedule
    assert schedule, "the Celery app has no beat schedule"
    for name, entry in schedule.items():
        assert f"`{name}`" in text and f"`{entry['task']}`" in text, name
    assert "every `GCPS_JOB_SWEEP_SECONDS`" in text


def test_the_doc_says_a_worker_may_exit_on_a_redis_outage_and_what_to_do():
    text = OPERATIONS.read_text()
    assert "workers reconnect and keep running;" not in text
    assert "a worker can also exit" in text
    assert "restart: unless-stopped" in text and "Restart=always" in text
