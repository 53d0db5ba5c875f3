"""A real S3 endpoint for the tests: ``moto_server`` (moto[server]) in its own process.

It speaks S3 over HTTP on 127.0.0.1, so the service's boto3 client, the API and worker
processes talk to it exactly as to MinIO or AWS. One server per session, started on first use;
each test gets a bucket of its own (``s3_bucket``). ``tests/conftest.py`` registers this module
as a plugin, so every test can ask for the fixtures.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

S3_ENV = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing",
          "AWS_DEFAULT_REGION": "us-east-1"}
"""Credentials and region moto accepts (any will do; boto3 needs some)."""


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def start_moto(log: Path, port: int | None = None) -> tuple[subprocess.Popen[bytes], str]:
    """Start ``moto_server`` on a free port; returns the process and its endpoint URL."""
    port = port or free_port()
    with log.open("wb") as handle:
        process = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1",
                                    "-p", str(port)], stdout=handle, stderr=subprocess.STDOUT)
    endpoint = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{endpoint}/moto-api/", timeout=1).status_code < 500:
                return process, endpoint
        except httpx.HTTPError:
            time.sleep(0.1)
    process.kill()
    raise RuntimeError(f"moto_server did not start:\n{log.read_text()[-2000:]}")


def s3_client(endpoint: str) -> Any:
    """A boto3 S3 client of the endpoint."""
    import boto3

    return boto3.client("s3", endpoint_url=endpoint, aws_access_key_id="testing",
                        aws_secret_access_key="testing", region_name="us-east-1")


@pytest.fixture(scope="session")
def moto_endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of a ``moto_server`` running for the session."""
    process, endpoint = start_moto(tmp_path_factory.mktemp("moto") / "moto.log")
    yield endpoint
    process.terminate()
    try:
        process.wait(10)
    except subprocess.TimeoutExpired:
        process.kill()


@pytest.fixture()
def s3_env(moto_endpoint: str, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """The AWS variables a process needs to reach the endpoint (also set in this one)."""
    env = {**S3_ENV, "AWS_ENDPOINT_URL": moto_endpoint}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return env


@pytest.fixture()
def s3_bucket(s3_env: dict[str, str]) -> str:
    """A new empty bucket's name on the endpoint."""
    name = f"cadnerf-{uuid.uuid4().hex[:12]}"
    s3_client(s3_env["AWS_ENDPOINT_URL"]).create_bucket(Bucket=name)
    return name


def bucket_objects(endpoint: str, bucket: str, prefix: str = "") -> dict[str, int]:
    """Key -> size of every object in the bucket under ``prefix``."""
    client = s3_client(endpoint)
    found: dict[str, int] = {}
    for page in client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix):
        for entry in page.get("Contents", []):
            found[entry["Key"]] = int(entry["Size"])
    return found


def service_s3_env(endpoint: str) -> dict[str, str]:
    """The AWS variables for a child process (its environment otherwise as this one's)."""
    return {**{k: v for k, v in os.environ.items() if not k.startswith("AWS_")}, **S3_ENV,
            "AWS_ENDPOINT_URL": endpoint}
