"""Schema-driven fuzzing (schemathesis): no generated request may produce a 5xx."""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, given, settings

from app.main import create_app
from app.state import Workers


def test_no_generated_request_makes_a_server_error(make_settings,  # type: ignore[no-untyped-def]
                                                   clean_redis) -> None:
    Workers(clean_redis).beat("fuzz-worker", 600)  # readiness answers 200, as with a worker
    schema = schemathesis.openapi.from_asgi("/openapi.json", create_app(make_settings()))
    checked = []
    for result in schema.get_all_operations():
        operation = result.ok()  # type: ignore[union-attr]

        @given(case=operation.as_strategy())
        @settings(max_examples=25, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck))
        def check(case) -> None:  # type: ignore[no-untyped-def]
            response = case.call()
            assert response.status_code < 500, (case.method, case.path, response.text[:300])

        check()
        checked.append(f"{operation.method.upper()} {operation.path}")
    assert "POST /v1/jobs" in checked and "GET /v1/jobs/{job_id}/artifacts/{name}" in checked
