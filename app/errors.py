"""Error answers: every failure is JSON ``{"error": {code, message, field/photo, hint}}``.

Handlers turn FastAPI's validation errors, Starlette's HTTP errors and anything unexpected into
that shape, so no client input can produce a bare 500 page or a traceback.
"""

from __future__ import annotations

import logging

import redis
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.schemas import ErrorBody
from app.state import ErrorDetail

log = logging.getLogger(__name__)


class ApiError(Exception):
    """An expected failure with a status code and a message for the client."""

    def __init__(self, status: int, code: str, message: str, *, field: str | None = None,
                 photo: str | None = None, hint: str | None = None,
                 headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.detail = ErrorDetail(code=code, message=message, field=field, photo=photo, hint=hint)
        self.headers = headers


def error_response(status: int, detail: ErrorDetail,
                   headers: dict[str, str] | None = None) -> JSONResponse:
    """The JSON answer for an error."""
    body = ErrorBody(error=detail).model_dump(exclude_none=True)
    return JSONResponse(body, status_code=status, headers=headers)


def not_found(what: str = "job") -> ApiError:
    """A 404 that does not reveal whether the thing exists for someone else."""
    return ApiError(404, "not_found", f"no such {what}",
                    hint="check the id; jobs are deleted after the retention period")


_STATUS_CODES = {400: "bad_request", 401: "unauthorized", 403: "forbidden", 404: "not_found",
                 405: "method_not_allowed", 406: "not_acceptable", 409: "conflict",
                 413: "too_large", 415: "unsupported_media_type", 416: "range_not_satisfiable",
                 422: "invalid", 429: "too_many_requests"}


async def _api_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    return error_response(exc.status, exc.detail, exc.headers)


async def _http_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    code = _STATUS_CODES.get(exc.status_code, "error")
    message = exc.detail if isinstance(exc.detail, str) else code.replace("_", " ")
    headers = dict(exc.headers) if exc.headers else None
    return error_response(exc.status_code, ErrorDetail(code=code, message=message), headers)


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    first = exc.errors()[0] if exc.errors() else {}
    loc = [str(p) for p in first.get("loc", ()) if p not in ("body", "query", "path", "header")]
    field = ".".join(loc) or None
    message = str(first.get("msg", "invalid request"))
    return error_response(422, ErrorDetail(code="invalid", message=message, field=field,
                                           hint="see the API description at /docs"))


STORE_RETRY_AFTER_S = 5


def store_unavailable() -> ApiError:
    """The 503 for a Redis that does not answer (the client should retry shortly)."""
    return ApiError(503, "store_unavailable", "the job store (Redis) is not reachable",
                    hint=f"try again in {STORE_RETRY_AFTER_S} seconds",
                    headers={"Retry-After": str(STORE_RETRY_AFTER_S)})


async def _redis_down(request: Request, exc: Exception) -> JSONResponse:
    log.warning("Redis unavailable on %s %s: %s", request.method, request.url.path, exc)
    error = store_unavailable()
    return error_response(error.status, error.detail, error.headers)


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unexpected error on %s %s", request.method, request.url.path)
    return error_response(500, ErrorDetail(code="internal", message="internal server error",
                                           hint="the error was logged; try again later"))


def install_handlers(app: FastAPI) -> None:
    """Register the JSON error handlers on an app."""
    app.add_exception_handler(ApiError, _api_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(redis.exceptions.ConnectionError, _redis_down)
    app.add_exception_handler(redis.exceptions.TimeoutError, _redis_down)
    app.add_exception_handler(Exception, _unexpected)
