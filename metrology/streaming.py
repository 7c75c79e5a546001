"""Streamed responses sent as they are read under ASGI, in bounded memory.

Django's ASGI handler sends a streaming response (``FileResponse``, ``StreamingHttpResponse``) whose
content is a *synchronous* iterator by first reading the whole iterator into a list
(``StreamingHttpResponse.__aiter__``): a 200 MB mesh would be held in memory whole, per download,
and its first byte sent only once the last was read. :class:`AsyncStreamingMiddleware`, first in
``MIDDLEWARE``, replaces such content with an asynchronous iterator that reads the synchronous one
in the request's own thread (``sync_to_async``, thread-sensitive: the same thread and database
connection as the view), :data:`BATCH_BYTES` at a time, so memory stays bounded and bytes go out
as they are produced, at the client's pace. Under WSGI (``runserver``, the embedded default) it
does nothing.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from typing import cast

from asgiref.sync import iscoroutinefunction, markcoroutinefunction, sync_to_async
from django.http import HttpRequest, HttpResponseBase, StreamingHttpResponse

BATCH_BYTES = 1 << 20
"""Bytes read from the synchronous iterator per hop to its thread (FileResponse reads 4 KiB blocks)."""


def _read_batch(chunks: Iterator[bytes]) -> bytes:
    parts: list[bytes] = []
    size = 0
    for part in chunks:
        parts.append(part)
        size += len(part)
        if size >= BATCH_BYTES:
            break
    return b"".join(parts)


async def _async_chunks(chunks: Iterator[bytes]) -> AsyncIterator[bytes]:
    read = sync_to_async(_read_batch)
    while batch := await read(chunks):
        yield batch


class AsyncStreamingMiddleware:
    """Under ASGI, give streaming responses with synchronous content an asynchronous iterator over it."""

    sync_capable = True
    async_capable = True

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponseBase | Awaitable[HttpResponseBase]]) -> None:
        self.get_response = get_response
        self.is_async = iscoroutinefunction(get_response)
        if self.is_async:
            markcoroutinefunction(self)

    def __call__(self, request: HttpRequest):  # sync or async, as Django chose
        if self.is_async:
            return self._acall(request)
        return self.get_response(request)

    async def _acall(self, request: HttpRequest) -> HttpResponseBase:
        response = await self.get_response(request)  # type: ignore[misc]  # async in this mode
        if isinstance(response, StreamingHttpResponse) and not response.is_async:
            response.streaming_content = _async_chunks(cast(Iterator[bytes], response.streaming_content))
        return response
