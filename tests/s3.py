"""A real S3-protocol server for the tests: moto's standalone server (``moto_server``), in its own process.

MinIO's server cannot be installed from the registries this project reaches (PyPI, Debian, npm
have its clients only), so the suite runs moto in server mode: a separate process speaking the S3
protocol over HTTP on a free loopback port, offline, installed by ``scripts/setup.sh --dev``
(``moto[server]`` in the dev extras). The application talks to it through django-storages and
boto3 exactly as it would talk to MinIO or AWS (``GCPS_S3_*`` settings, docs/storage.md).
"""

from __future__ import annotations

import contextlib
import secrets
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import requests

from tests.processes import free_port, stop_group

ACCESS_KEY = "gcps-test-key"
SECRET_KEY = "gcps-test-secret"
REGION = "us-east-1"


class S3Server:
    """``moto_server`` on ``127.0.0.1:<free port>``; :meth:`bucket` makes a fresh private bucket."""

    def __init__(self, log: Path) -> None:
        self.port = free_port()
        self.endpoint_url = f"http://127.0.0.1:{self.port}"
        executable = Path(sys.executable).with_name("moto_server")
        command = [str(executable)] if executable.exists() else [sys.executable, "-m", "moto.server"]
        self._log = log.open("ab")
        self.process = subprocess.Popen(
            [*command, "-H", "127.0.0.1", "-p", str(self.port)],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 60
        while True:
            try:
                requests.get(self.endpoint_url, timeout=2)
                break
            except requests.ConnectionError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise AssertionError(f"moto_server did not start; see {log}") from None
                time.sleep(0.1)

    def client(self) -> Any:
        import boto3

        return boto3.client(
            "s3",
            endpoint_url=self.endpoint_url,
            aws_access_key_id=ACCESS_KEY,
            aws_secret_access_key=SECRET_KEY,
            region_name=REGION,
        )

    def bucket(self) -> str:
        """A new, empty bucket's name."""
        name = f"gcps-{secrets.token_hex(6)}"
        self.client().create_bucket(Bucket=name)
        return name

    def env(self, bucket: str) -> dict[str, str]:
        """The ``GCPS_S3_*`` environment of a process that stores in ``bucket``."""
        return {
            "GCPS_S3_BUCKET": bucket,
            "GCPS_S3_ENDPOINT_URL": self.endpoint_url,
            "GCPS_S3_ACCESS_KEY_ID": ACCESS_KEY,
            "GCPS_S3_SECRET_ACCESS_KEY": SECRET_KEY,
            "GCPS_S3_REGION": REGION,
        }

    def storages(self, bucket: str) -> dict[str, dict[str, Any]]:
        """``settings.STORAGES`` of an in-process test storing in ``bucket`` (as metrology/settings.py builds it)."""
        from django.conf import settings

        return {
            **settings.STORAGES,
            "default": {
                "BACKEND": "storages.backends.s3.S3Storage",
                "OPTIONS": {
                    "bucket_name": bucket,
                    "endpoint_url": self.endpoint_url,
                    "access_key": ACCESS_KEY,
                    "secret_key": SECRET_KEY,
                    "region_name": REGION,
                    "default_acl": None,
                    "querystring_auth": True,
                    "file_overwrite": True,
                    "signature_version": "s3v4",
                    "addressing_style": "path",
                },
            },
        }

    def objects(self, bucket: str) -> dict[str, int]:
        """``{key: size}`` of every object in ``bucket``."""
        found = {}
        for page in self.client().get_paginator("list_objects_v2").paginate(Bucket=bucket):
            for item in page.get("Contents", []):
                found[item["Key"]] = item["Size"]
        return found

    def stop(self) -> None:
        stop_group(self.process)
        self._log.close()


@contextlib.contextmanager
def s3_server(log: Path) -> Iterator[S3Server]:
    server = S3Server(log)
    try:
        yield server
    finally:
        server.stop()
