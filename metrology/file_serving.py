"""Send a file of a Django storage as a download: with HTTP range requests, by the reverse proxy, or from S3.

One function, :func:`storage_file_response`, for every stored file the API serves (result files,
derived meshes and TIFFs). It never asks the storage for a local path. Three ways, chosen by the
storage and the settings:

- ``GCPS_ACCEL_REDIRECT`` on, local storage (behind ``deploy/nginx/gcps.conf``): an empty answer
  with ``X-Accel-Redirect: /protected/<storage name>``; nginx sends the file from its ``internal``
  location (ranges, any client speed, no web worker held).
- ``GCPS_ACCEL_REDIRECT`` on, S3 storage (the documented topology: the bucket is not reachable from
  outside): an empty answer with ``X-Accel-Redirect: /protected-s3/<bucket>/<key>?<presigned query>``;
  nginx's ``internal`` location ``/protected-s3/`` forwards it to the S3 endpoint with the ``Host``
  the URL was signed for, and streams the object (and its ranges) to the client.
- S3 storage otherwise: ``302`` to a presigned URL of the object, valid ``GCPS_S3_URL_SECONDS``
  (300 s by default), carrying the attachment name and content type; the S3 server answers ranges
  itself (the client must reach ``GCPS_S3_ENDPOINT_URL``).
- otherwise: the file streamed by the app from ``storage.open``, ``Accept-Ranges: bytes``; a single
  ``Range: bytes=a-b`` (or ``a-``, ``-n``) answers ``206`` with ``Content-Range``, a range past the
  end ``416`` with ``Content-Range: bytes */size``; several ranges, or an ``If-Range``, answer the
  whole file (``200``), as RFC 9110 allows.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import IO
from urllib.parse import quote, urlsplit

from django.conf import settings
from django.core.files.storage import FileSystemStorage, Storage
from django.http import FileResponse, HttpRequest, HttpResponse, HttpResponseRedirect, StreamingHttpResponse
from django.http.response import HttpResponseBase
from django.utils.http import content_disposition_header

ACCEL_PREFIX = "/protected/"
"""The nginx ``internal`` location that maps to MEDIA_ROOT (``deploy/nginx/gcps.conf``)."""

ACCEL_S3_PREFIX = "/protected-s3"
"""The nginx ``internal`` location that forwards a presigned path-style request to the S3 endpoint."""

CHUNK_BYTES = 1 << 20
"""Bytes per chunk of a streamed range."""

_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


def parse_range(header: str, size: int) -> tuple[int, int] | str | None:
    """The byte range ``(start, end)`` (both inclusive) of a ``Range`` header for a file of ``size`` bytes.

    Returns None when the header is absent, malformed or asks for several ranges (send the whole
    file), or ``"unsatisfiable"`` when the range starts past the end (answer 416).
    """
    match = _RANGE.match(header.strip()) if header else None
    if match is None:
        return None
    first, last = match.groups()
    if not first and not last:
        return None
    if not first:  # the last n bytes
        suffix = int(last)
        if suffix == 0:
            return "unsatisfiable"
        return max(0, size - suffix), size - 1
    start = int(first)
    end = size - 1 if not last else min(int(last), size - 1)
    if last and int(last) < start:
        return None
    if start >= size:
        return "unsatisfiable"
    return start, end


def _read_range(handle: IO[bytes], start: int, length: int) -> Iterator[bytes]:
    try:
        handle.seek(start)
        left = length
        while left > 0:
            chunk = handle.read(min(CHUNK_BYTES, left))
            if not chunk:
                break
            left -= len(chunk)
            yield chunk
    finally:
        handle.close()


def _presigned_url(storage: Storage, name: str, disposition: str, content_type: str) -> str | None:
    try:
        from storages.backends.s3 import S3Storage
    except ImportError:  # pragma: no cover - django-storages is a dependency
        return None
    if not isinstance(storage, S3Storage):
        return None
    parameters = {"ResponseContentDisposition": disposition, "ResponseContentType": content_type}
    return str(storage.url(name, parameters=parameters, expire=settings.GCPS_S3_URL_SECONDS))


def storage_file_response(
    request: HttpRequest, storage: Storage, name: str, *, filename: str, content_type: str
) -> HttpResponseBase:
    """The download of the file ``name`` of ``storage`` as the attachment ``filename`` (see the module's doc)."""
    disposition = content_disposition_header(True, filename) or f'attachment; filename="{filename}"'
    local = isinstance(storage, FileSystemStorage)
    if local and settings.GCPS_ACCEL_REDIRECT:
        response = HttpResponse(content_type=content_type)
        response["X-Accel-Redirect"] = ACCEL_PREFIX + quote(name)
        response["Content-Disposition"] = disposition
        return response
    url = None if local else _presigned_url(storage, name, disposition, content_type)
    if url is not None and settings.GCPS_ACCEL_REDIRECT:
        signed = urlsplit(url)  # path-style: /<bucket>/<key>, signed for the endpoint's host
        response = HttpResponse(content_type=content_type)
        response["X-Accel-Redirect"] = f"{ACCEL_S3_PREFIX}{signed.path}?{signed.query}"
        return response
    if url is not None:
        return HttpResponseRedirect(url)
    size = storage.size(name)
    wanted = None if request.headers.get("If-Range") else parse_range(request.headers.get("Range", ""), size)
    if wanted == "unsatisfiable":
        refused = HttpResponse(status=416)
        refused["Content-Range"] = f"bytes */{size}"
        refused["Accept-Ranges"] = "bytes"
        return refused
    handle = storage.open(name, "rb")
    if isinstance(wanted, tuple):
        start, end = wanted
        partial = StreamingHttpResponse(
            _read_range(handle, start, end - start + 1), status=206, content_type=content_type
        )
        partial["Content-Range"] = f"bytes {start}-{end}/{size}"
        partial["Content-Length"] = str(end - start + 1)
        partial["Content-Disposition"] = disposition
        partial["Accept-Ranges"] = "bytes"
        return partial
    whole = FileResponse(handle, content_type=content_type)
    whole["Content-Length"] = str(size)
    whole["Content-Disposition"] = disposition
    whole["Accept-Ranges"] = "bytes"
    return whole
