"""One request, HTTP or gRPC, reduced to what the checks look at: a status string and the
time it took. HTTP statuses are their numbers ("200", "429"); gRPC ones their code names
("OK", "RESOURCE_EXHAUSTED"). What never got an answer is "conn-error" (refused, reset,
closed without an answer, UNAVAILABLE) or "timeout" (the client gave up: a hang, or a
DEADLINE_EXCEEDED, which the server sends only past its 120 s request limit)."""

from __future__ import annotations

import http.client
import socket
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional
from urllib.parse import urlsplit

import b2tfpose

NO_ANSWER = ("conn-error", "timeout")


@dataclass
class Reply:
    status: str
    seconds: float
    body: Any = None  # bytes for HTTP, the client's return value for gRPC
    detail: str = ""


def http_call(base: str, method: str, path: str, body: Optional[bytes] = None, ctype: str = "application/json", timeout: float = 60) -> Reply:
    """One request on its own connection (as many clients do: it exercises accept and
    close, where descriptor leaks would show)."""
    u = urlsplit(base)
    t0 = time.monotonic()
    conn = http.client.HTTPConnection(u.hostname or "127.0.0.1", u.port, timeout=timeout)
    try:
        headers = {"Content-Type": ctype} if body is not None else {}
        try:
            conn.request(method, path, body=body, headers=headers)
        except (BrokenPipeError, ConnectionResetError):
            # A server may answer (413) and close before reading a body it refuses by its
            # announced length: the answer is still there to read.
            pass
        r = conn.getresponse()
        data = r.read()
        return Reply(str(r.status), time.monotonic() - t0, data)
    except (socket.timeout, TimeoutError) as e:
        return Reply("timeout", time.monotonic() - t0, detail=f"{method} {path}: {e!r}")
    except (OSError, http.client.HTTPException) as e:
        return Reply("conn-error", time.monotonic() - t0, detail=f"{method} {path}: {e!r}")
    finally:
        conn.close()


def grpc_call(fn: Callable[[], Any]) -> Reply:
    """`fn` makes one call with a b2tfpose.Client (retries off, its own timeout)."""
    t0 = time.monotonic()
    try:
        value = fn()
        return Reply("OK", time.monotonic() - t0, value)
    except b2tfpose.RpcError as e:
        name = e.code.name
        status = {"UNAVAILABLE": "conn-error", "DEADLINE_EXCEEDED": "timeout", "CANCELLED": "conn-error"}.get(name, name)
        return Reply(status, time.monotonic() - t0, detail=f"{e.method}: {name}: {e.message}"[:300])
