"""Schema fuzzing: schemathesis generates requests from the service's OpenAPI description and
sends them to the ASGI app (real Redis); no answer may be a 5xx, and every answer must match the
status codes, content types, headers and bodies the description declares."""

from __future__ import annotations

from typing import Any

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis import GenerationMode, checks

from app.main import create_app

MAX_EXAMPLES = 12  # per operation and generation mode: bounded, a few seconds each

CHECKS = [checks.not_a_server_error, checks.status_code_conformance,
          checks.content_type_conformance, checks.response_headers_conformance,
          checks.response_schema_conformance]


OPERATIONS = ["POST /v1/jobs", "GET /v1/jobs", "GET /v1/jobs/{job_id}",
              "DELETE /v1/jobs/{job_id}", "GET /v1/jobs/{job_id}/result",
              "GET /v1/jobs/{job_id}/artifacts/{name}", "GET /v1/library", "GET /v1/info",
              "GET /v1/usage", "GET /healthz", "GET /readyz"]


CASES = [(label, mode) for label in OPERATIONS for mode in GenerationMode
         if mode == GenerationMode.POSITIVE or not label.endswith(("/healthz", "/readyz"))]


@pytest.mark.parametrize(("label", "mode"), CASES)
def test_no_server_error_and_responses_match_the_schema(make_settings: Any, label: str,
                                                        mode: GenerationMode) -> None:
    app = create_app(make_settings())
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    method, path = label.split(" ", 1)
    operation = schema[path][method]
    seen: list[int] = []

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(max_examples=MAX_EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    def fuzz(case: Any) -> None:
        response = case.call()
        seen.append(response.status_code)
        # /readyz answers a documented 503 here: no worker runs in this test.
        chosen = CHECKS[1:] if label == "GET /readyz" else CHECKS
        case.validate_response(response, checks=chosen)

    try:
        fuzz()
    finally:
        app.state.store.close()
    assert seen and all(status < 500 or label == "GET /readyz" for status in seen), seen


def test_the_description_covers_the_contract(make_settings: Any) -> None:
    """The fuzzer saw every route of the HTTP contract (an empty schema would pass trivially)."""
    app = create_app(make_settings())
    spec = app.openapi()
    app.state.store.close()
    expected = {("/v1/jobs", "post"), ("/v1/jobs", "get"), ("/v1/jobs/{job_id}", "get"),
                ("/v1/jobs/{job_id}", "delete"), ("/v1/jobs/{job_id}/result", "get"),
                ("/v1/jobs/{job_id}/artifacts/{name}", "get"), ("/v1/library", "get"),
                ("/v1/usage", "get"), ("/healthz", "get"), ("/readyz", "get")}
    present = {(path, method) for path, item in spec["paths"].items() for method in item}
    assert expected <= present, expected - present
