"""Under ASGI, a streamed response with synchronous content is sent as it is read, in bounded memory."""

from __future__ import annotations

import asyncio

from django.http import HttpRequest, HttpResponse, StreamingHttpResponse
from django.test import RequestFactory

from metrology.streaming import BATCH_BYTES, AsyncStreamingMiddleware

CHUNK = 64 * 1024
CHUNKS = 64  # 4 MiB in all


def test_sync_streaming_content_is_read_in_batches_as_the_client_takes_them():
    produced: list[int] = []

    def content():
        for index in range(CHUNKS):
            produced.append(index)
            yield bytes([index % 256]) * CHUNK

    async def view(request: HttpRequest) -> StreamingHttpResponse:
        return StreamingHttpResponse(content())

    async def run() -> tuple[int, bytes]:
        response = await AsyncStreamingMiddleware(view)(RequestFactory().get("/"))
        assert response.is_async
        stream = aiter(response.streaming_content)
        first = await anext(stream)
        after_first = len(produced)
        rest = [part async for part in stream]
        return after_first, first + b"".join(rest)

    after_first, body = asyncio.run(run())
    # Django alone would have read all 64 chunks before sending the first byte
    assert after_first == BATCH_BYTES // CHUNK < CHUNKS
    assert body == b"".join(bytes([index % 256]) * CHUNK for index in range(CHUNKS))


def test_under_wsgi_responses_pass_through():
    response = HttpResponse(b"x")
    assert AsyncStreamingMiddleware(lambda request: response)(RequestFactory().get("/")) is response
