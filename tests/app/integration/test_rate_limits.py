"""Rate limits under real concurrency (issue 23 item 5): threads against the documented web server (two
worker processes) with the rate counts in the real Redis cache."""

from __future__ import annotations

import secrets
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator

import pytest
import redis
import requests

from tests.app.integration.harness import Stack, migrated_stack, template_user_token

pytestmark = pytest.mark.integration

USER_LIMIT = 150
BAD_TOKEN_LIMIT = 20


@pytest.fixture(scope="module")
def limited_server(tmp_path_factory) -> Iterator[Stack]:
    """The server with the rates above, started once for the module's tests (its start, two worker
    processes, costs about 1.5 s of CPU): :func:`limited_stack` gives each test fresh counts."""
    folder = tmp_path_factory.mktemp("limited")
    (folder / "media").mkdir()
    with migrated_stack(folder, folder / "media") as stack:
        stack.env["GCPS_THROTTLE_USER"] = f"{USER_LIMIT}/minute"
        stack.env["GCPS_THROTTLE_BAD_TOKEN"] = f"{BAD_TOKEN_LIMIT}/minute"
        stack.start_asgi(workers=2)
        yield stack


@pytest.fixture
def limited_stack(limited_server: Stack) -> Stack:
    """:func:`limited_server` with no request counted yet, as a server of its own would start: the
    rate counts live in the Redis cache under the stack's key prefix (``GCPS_CACHE_KEY_PREFIX``),
    which nothing else uses; they are deleted before the test."""
    prefix = limited_server.env["GCPS_CACHE_KEY_PREFIX"]
    client = redis.Redis.from_url(limited_server.env["REDIS_URL"])
    counts = list(client.scan_iter(f"{prefix}:*", count=1000))
    if counts:
        client.delete(*counts)
    assert not list(client.scan_iter(f"{prefix}:*", count=1000))
    return limited_server


def token_of(stack: Stack) -> str:
    return template_user_token()


def in_parallel(threads: int, calls: int, call: Callable[[requests.Session], int]) -> Counter[int]:
    codes: Counter[int] = Counter()
    lock = threading.Lock()
    barrier = threading.Barrier(threads)

    def run() -> None:
        with requests.Session() as session:
            barrier.wait()
            for _ in range(calls):
                code = call(session)
                with lock:
                    codes[code] += 1

    workers = [threading.Thread(target=run) for _ in range(threads)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=120)
    return codes


def test_parallel_requests_pass_no_more_than_the_user_limit(limited_stack):
    base, token = limited_stack.base_url, token_of(limited_stack)
    started = time.monotonic()

    def call(session: requests.Session) -> int:
        return session.get(f"{base}/api/rigs/", headers={"Authorization": f"Token {token}"}, timeout=60).status_code

    codes = in_parallel(16, 25, call)  # 400 requests at a limit of 150
    elapsed = time.monotonic() - started
    assert set(codes) <= {200, 429}, codes
    assert codes[200] <= USER_LIMIT, codes
    if elapsed < 55:  # all within one window: exactly the limit passed, none lost to the counting either
        assert codes[200] == USER_LIMIT, codes


def test_a_bad_token_is_refused_while_valid_tokens_from_the_same_address_keep_working(limited_stack):
    base, token = limited_stack.base_url, token_of(limited_stack)
    bad: Counter[int] = Counter()
    good: list[int] = []

    def guess() -> None:
        bad.update(
            in_parallel(
                8,
                10,
                lambda s: (
                    s.get(
                        f"{base}/api/rigs/", headers={"Authorization": f"Token {secrets.token_hex(20)}"}, timeout=60
                    ).status_code
                ),
            )
        )

    guesser = threading.Thread(target=guess)
    guesser.start()
    with requests.Session() as session:
        while guesser.is_alive() or len(good) < 20:
            good.append(
                session.get(f"{base}/api/rigs/", headers={"Authorization": f"Token {token}"}, timeout=60).status_code
            )
    guesser.join()
    assert bad == Counter({401: BAD_TOKEN_LIMIT, 429: 80 - BAD_TOKEN_LIMIT}), bad
    assert set(good) == {200}, Counter(good)
