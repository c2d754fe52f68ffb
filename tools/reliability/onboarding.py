"""Starting an onboarding of the sample box three ways (HTTP JSON, HTTP multipart, gRPC)
and following its operation over HTTP: what the crash and full-disk tests do to have a
put under way when they strike."""

from __future__ import annotations

import json
import time
from typing import Any, Dict, Optional, Tuple

import b2tfpose

from .calls import Reply, grpc_call, http_call
from .fixtures import Fixtures

WAYS = ("json", "multipart", "grpc")


def start(http: str, client: b2tfpose.Client, fx: Fixtures, oid: str, level: int, in_plane: int, how: str, timeout: float = 60, patch_rows: Optional[str] = None) -> Tuple[Reply, Optional[str]]:
    """(the answer, the operation id when accepted). `client` is a b2tfpose.Client made
    with retries off and the timeout wanted. `patch_rows` (gRPC only; None: the server's
    default) sets how many bytes the object takes."""
    if how == "grpc":
        r = grpc_call(lambda: client.onboard(oid, fx.obj, format="obj", units="m", resources=fx.resources, level=level, in_plane=in_plane, patch_rows=patch_rows, wait=False))
        return r, (r.body.id if r.status == "OK" else None)
    if patch_rows is not None:
        raise ValueError("patch_rows is passed over gRPC only")
    if how == "json":
        body, ctype = fx.onboard_json(oid, level, in_plane), "application/json"
    else:
        body, ctype = fx.onboard_multipart(oid, level, in_plane)
    r = http_call(http, "POST", "/v1/objects", body, ctype, timeout=timeout)
    return r, (json.loads(r.body)["id"] if r.status == "202" else None)


def state(http: str, op: str) -> Dict[str, Any]:
    """The operation's JSON (`state`, `templates_done`, `templates_total`, `error`), or
    {"state": "<HTTP status>"} when there is none to read."""
    r = http_call(http, "GET", f"/v1/operations/{op}", timeout=30)
    return json.loads(r.body) if r.status == "200" else {"state": r.status, "detail": r.detail}


def wait(http: str, op: str, timeout: float = 300, poll: float = 0.1) -> Dict[str, Any]:
    """Polls every `poll` seconds until the operation is no longer running (or `timeout`)."""
    end = time.monotonic() + timeout
    while True:
        s = state(http, op)
        if s["state"] != "running" or time.monotonic() > end:
            return s
        time.sleep(poll)


def onboard(http: str, client: b2tfpose.Client, fx: Fixtures, oid: str, level: int, in_plane: int, how: str = "json", patch_rows: Optional[str] = None) -> Dict[str, Any]:
    """Onboards and waits: the final operation JSON (its `state` says how it ended)."""
    r, op = start(http, client, fx, oid, level, in_plane, how, patch_rows=patch_rows)
    if op is None:
        raise RuntimeError(f"onboarding {oid} refused: {r.status} {r.detail} {r.body!r}"[:400])
    return wait(http, op)
