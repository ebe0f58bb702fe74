"""Strict JSON bodies: a syntax error is a 400 naming its line and column.

``JsonBodyRoute`` (the route class of a router) decodes the body of its routes that take one
with ``decode_json`` before FastAPI reads it (``media_type`` checked its type first), so FastAPI
validates the decoded value. Starlette's plain ``json.loads`` would accept NaN and UTF-16,
answer an empty body as a missing one, and fail with a 500 on deep nesting."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Coroutine
from typing import Any

from fastapi import Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute

from service.api.errors import JSON_INVALID, invalid
from service.api.media_type import UNSAFE_METHODS, check_unsafe_request
from service.api.schemas import Problem

EMPTY_BODY = 'the request body is empty: send a mission document or {"example": name}'


def _syntax(message: str) -> RequestValidationError:
    return invalid([Problem(loc=["body"], msg=message, type=JSON_INVALID)])


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} is out of range")
    return value


def _has_nul(value: Any) -> bool:
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            if "\x00" in item:
                return True
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return False


def decode_json(raw: bytes) -> Any:
    """The JSON value of ``raw``; a ``RequestValidationError`` (400) naming the line and column
    of a syntax error. NaN, Infinity, out-of-range numbers and NUL characters are rejected (the
    databases cannot store them)."""
    if not raw.strip():
        raise _syntax(EMPTY_BODY)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        raise _syntax(f"the body is not UTF-8 text: {error.reason} at byte {error.start}") from None
    try:
        value = json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float)
    except json.JSONDecodeError as error:
        message = f"invalid JSON at line {error.lineno}, column {error.colno}: {error.msg}"
        raise _syntax(message) from None
    except RecursionError:
        raise _syntax("invalid JSON: nested too deeply") from None
    except ValueError as error:
        raise _syntax(f"invalid JSON: {error}") from None
    if _has_nul(value):
        raise _syntax("invalid JSON: strings must not contain the NUL character (\\u0000)")
    return value


class JsonBodyRequest(Request):
    """A request whose ``json()`` is ``decode_json`` of its body (decoded once)."""

    _decoded: Any

    async def json(self) -> Any:
        """The decoded body (see ``decode_json``)."""
        if not hasattr(self, "_decoded"):
            self._decoded = decode_json(await self.body())
        return self._decoded


class JsonBodyRoute(APIRoute):
    """A route whose body, if it takes one, is decoded by ``decode_json`` up front, and whose
    state-changing requests must be JSON (``media_type.check_unsafe_request``: 403, 415)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        unsafe = bool((self.methods or set()) & UNSAFE_METHODS)
        takes_body = self.body_field is not None
        if not (takes_body or unsafe):
            return handler

        async def decoded_handler(request: Request) -> Response:
            request = JsonBodyRequest(request.scope, request.receive)
            if unsafe:
                # Read first (within the body limit: an oversize body is 413 whatever its
                # type), then check its type before anything parses or authenticates it.
                check_unsafe_request(request, await request.body())
            if takes_body:
                await request.json()
            return await handler(request)

        return decoded_handler
