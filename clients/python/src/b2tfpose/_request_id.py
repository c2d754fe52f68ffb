"""Request ids chosen by the caller: calls made inside ``with b2tfpose.request_id("…"):``
send it as ``x-request-id``, and the server uses it in its answer, log lines and trace
(instead of one of its own), so a caller's own trace or job id finds them."""

from __future__ import annotations

import contextlib
import contextvars
import re
from typing import Iterator, Optional

# What the server keeps as it is; anything else it would replace with its own.
_SANE = re.compile(r"[A-Za-z0-9._:-]{1,64}")
_CURRENT: "contextvars.ContextVar[Optional[str]]" = contextvars.ContextVar("b2tfpose_request_id", default=None)


@contextlib.contextmanager
def request_id(value: str) -> Iterator[str]:
    """Sends ``value`` as the request id of every call made in this block (this thread or
    asyncio task only). ``value``: 1–64 characters of ``A-Za-z0-9._:-``."""
    if not isinstance(value, str) or not _SANE.fullmatch(value):
        raise ValueError(f"request id {value!r}: expected 1-64 characters of A-Za-z0-9._:-")
    token = _CURRENT.set(value)
    try:
        yield value
    finally:
        _CURRENT.reset(token)


def current() -> Optional[str]:
    return _CURRENT.get()
