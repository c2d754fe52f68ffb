"""The load test's requests: estimates, onboardings, reads, bad requests and clients that
give up (hang up, or a short gRPC deadline) over HTTP and gRPC, each with the statuses it
may get. Anything else is a violation: a 5xx, an error
the request did not deserve, no answer at all, or a wrong pose.

Why 429 is allowed for some bad requests: an estimate takes its concurrency slot before
the core reads the image or looks the object up, so when the server is full a bad
estimate is refused before anyone notices it is bad. Onboardings are parsed before their
slot is taken, so a bad one is always 400 / INVALID_ARGUMENT."""

from __future__ import annotations

import itertools
import json
import threading
import time
from dataclasses import dataclass
from typing import Callable, Dict, FrozenSet, List, Tuple

import b2tfpose

from . import onboarding
from .calls import Reply, grpc_call, http_call
from .fixtures import K, Fixtures, pose_is_right

OBJECT = "box"  # onboarded before the load; every estimate names it
ABANDON_S = 0.3  # how long a client that gives up waits


@dataclass
class Outcome:
    kind: str  # e.g. "estimate", "onboard", "bad", "read", "onboard-done", "delete"
    proto: str  # "http" | "grpc"
    status: str
    seconds: float
    start: float  # time.monotonic() when sent
    ok: bool  # the status is one this request may get
    detail: str = ""


def outcome(kind: str, proto: str, reply: Reply, start: float, allowed: FrozenSet[str], detail: str = "") -> Outcome:
    ok = reply.status in allowed
    return Outcome(kind, proto, reply.status, reply.seconds, start, ok, "" if ok else (detail or reply.detail or repr(reply.body)[:300]))


HTTP_EST = frozenset({"200", "429"})
GRPC_EST = frozenset({"OK", "RESOURCE_EXHAUSTED"})


class Mix:
    """The requests, sharing prebuilt bodies and one gRPC client (one HTTP/2 connection);
    each HTTP request opens its own connection."""

    def __init__(self, fx: Fixtures, http: str, grpc: str, timeout: float, max_body_mb: int, onboard_level: Tuple[int, int] = (0, 1)) -> None:
        self.fx, self.http, self.timeout = fx, http, timeout
        self.client = b2tfpose.Client(grpc, timeout=timeout, retry=b2tfpose.NO_RETRY)
        self.level, self.in_plane = onboard_level
        self.estimate_body = fx.estimate_json(OBJECT)
        self.oversized = b"x" * (max_body_mb * 1024 * 1024 + 1024)
        self.bad_png = fx.rgb_png[:200]  # a PNG header, then nothing: undecodable
        self._ids = itertools.count()
        self._bad_http = itertools.cycle(self._bad_http_cases())
        self._bad_grpc = itertools.cycle(self._bad_grpc_cases())
        self._reads_http = itertools.cycle(["/v1/objects", f"/v1/objects/{OBJECT}", "/healthz", "/metrics"])
        self._reads_grpc = itertools.cycle(["list", "get", "health"])
        self._onboards = itertools.cycle(onboarding.WAYS)
        self._lock = threading.Lock()

    def close(self) -> None:
        self.client.close()

    # ------------------------------------------------------------------ estimates

    def estimate_http(self) -> List[Outcome]:
        t = time.monotonic()
        r = http_call(self.http, "POST", "/v1/estimate", self.estimate_body, timeout=self.timeout)
        if r.status == "200":
            res = json.loads(r.body)["results"][0]
            if not res.get("pose") or not pose_is_right(res["pose"]["t"]):
                return [Outcome("estimate", "http", "wrong-pose", r.seconds, t, False, json.dumps(res)[:300])]
        return [outcome("estimate", "http", r, t, HTTP_EST)]

    def estimate_grpc(self) -> List[Outcome]:
        t = time.monotonic()
        r = grpc_call(lambda: self.client.estimate(self.fx.rgb_png, K, [b2tfpose.Detection(OBJECT, mask=self.fx.mask_png, score=0.9)]))
        if r.status == "OK":
            res = r.body[0]
            if res.pose is None or not pose_is_right(list(res.pose.t)):
                return [Outcome("estimate", "grpc", "wrong-pose", r.seconds, t, False, repr(res)[:300])]
        return [outcome("estimate", "grpc", r, t, GRPC_EST)]

    # ------------------------------------------------------------------ clients giving up

    def abandon_http(self) -> List[Outcome]:
        """An estimate whose client hangs up after 0.3 s (an accepted one takes ~1 s):
        the server must finish or drop the work and free its slot and connection."""
        t = time.monotonic()
        r = http_call(self.http, "POST", "/v1/estimate", self.estimate_body, timeout=ABANDON_S)
        return [outcome("abandon", "http", r, t, HTTP_EST | {"timeout"})]

    def abandon_grpc(self) -> List[Outcome]:
        """An estimate with a 0.3 s gRPC deadline: DEADLINE_EXCEEDED (shown as "timeout"),
        and the slot freed once the worker notices."""
        t = time.monotonic()
        r = grpc_call(lambda: self.client.estimate(self.fx.rgb_png, K, [b2tfpose.Detection(OBJECT, mask=self.fx.mask_png)], timeout=ABANDON_S))
        return [outcome("abandon", "grpc", r, t, GRPC_EST | {"timeout"})]

    # ------------------------------------------------------------------ reads

    def read_http(self) -> List[Outcome]:
        with self._lock:
            path = next(self._reads_http)
        t = time.monotonic()
        return [outcome("read", "http", http_call(self.http, "GET", path, timeout=self.timeout), t, frozenset({"200"}), path)]

    def read_grpc(self) -> List[Outcome]:
        with self._lock:
            which = next(self._reads_grpc)
        call: Dict[str, Callable[[], object]] = {"list": self.client.list_objects, "get": lambda: self.client.get_object(OBJECT), "health": self.client.health}
        t = time.monotonic()
        return [outcome("read", "grpc", grpc_call(call[which]), t, frozenset({"OK"}), which)]

    # ------------------------------------------------------------------ bad requests

    def _bad_http_cases(self) -> List[Tuple[str, str, bytes, str, FrozenSet[str]]]:
        fx = self.fx
        unknown = fx.estimate_json("no-such-object")
        bad_image = json.loads(self.estimate_body)
        bad_image["image"]["encoded"] = "bm90IGFuIGltYWdl"  # "not an image"
        bad_mesh = json.loads(fx.onboard_json("bad-mesh", 0, 1))
        bad_mesh["mesh"]["data"] = "bm90IGFuIE9CSg=="  # "not an OBJ"
        j = "application/json"
        return [
            ("POST", "/v1/estimate", b"{not json", j, frozenset({"400"})),
            ("POST", "/v1/estimate", unknown, j, frozenset({"404", "429"})),
            ("POST", "/v1/estimate", json.dumps(bad_image).encode(), j, frozenset({"400", "429"})),
            ("POST", "/v1/estimate", self.oversized, j, frozenset({"413"})),
            ("POST", "/v1/objects", json.dumps(bad_mesh).encode(), j, frozenset({"400"})),
            ("GET", "/v1/operations/op-none", b"", j, frozenset({"404"})),
        ]

    def bad_http(self) -> List[Outcome]:
        with self._lock:
            method, path, body, ctype, allowed = next(self._bad_http)
        t = time.monotonic()
        r = http_call(self.http, method, path, body if method == "POST" else None, ctype, timeout=self.timeout)
        return [outcome("bad", "http", r, t, allowed, f"{method} {path} ({len(body)} B): {r.status} {r.detail or r.body!r}"[:300])]

    def _bad_grpc_cases(self) -> List[Tuple[str, Callable[[], object], FrozenSet[str]]]:
        c, fx = self.client, self.fx
        return [
            ("estimate unknown object", lambda: c.estimate(fx.rgb_png, K, [b2tfpose.Detection("no-such-object", mask=fx.mask_png)]), frozenset({"NOT_FOUND", "RESOURCE_EXHAUSTED"})),
            ("estimate undecodable PNG", lambda: c.estimate(self.bad_png, K, [b2tfpose.Detection(OBJECT, mask=fx.mask_png)]), frozenset({"INVALID_ARGUMENT", "RESOURCE_EXHAUSTED"})),
            ("estimate oversized", lambda: c.estimate(fx.rgb_png[:24] + self.oversized, K, [b2tfpose.Detection(OBJECT, mask=fx.mask_png)]), frozenset({"INVALID_ARGUMENT"})),
            ("get unknown object", lambda: c.get_object("no-such-object"), frozenset({"NOT_FOUND"})),
            ("onboard bad mesh", lambda: c.onboard("bad-mesh", b"not an OBJ", format="obj", units="m", level=0, in_plane=1, wait=False), frozenset({"INVALID_ARGUMENT"})),
        ]

    def bad_grpc(self) -> List[Outcome]:
        with self._lock:
            what, fn, allowed = next(self._bad_grpc)
        t = time.monotonic()
        r = grpc_call(fn)
        return [outcome("bad", "grpc", r, t, allowed, f"{what}: {r.status} {r.detail}")]

    # ------------------------------------------------------------------ onboardings

    def onboard(self) -> List[Outcome]:
        """A new object (a fresh id, the box at a small level): refused at once over
        --max-onboardings, else followed to its end (it must succeed), then deleted."""
        with self._lock:
            how, oid = next(self._onboards), f"load-{next(self._ids)}"
        t = time.monotonic()
        r, op = onboarding.start(self.http, self.client, self.fx, oid, self.level, self.in_plane, how, self.timeout)
        if how == "grpc":
            first = outcome("onboard", "grpc", r, t, GRPC_EST)
            return [first] if op is None else [first, *self._follow_grpc(oid, op, t)]
        first = outcome("onboard", "http", r, t, frozenset({"202", "429"}), f"{how}: {r.status} {r.body!r}"[:300])
        return [first] if op is None else [first, *self._follow_http(oid, op, t)]

    def _follow_http(self, oid: str, op: str, t: float) -> List[Outcome]:
        end = t + self.timeout * 4
        while True:
            r = http_call(self.http, "GET", f"/v1/operations/{op}", timeout=self.timeout)
            state = json.loads(r.body).get("state") if r.status == "200" else None
            if state != "running" or time.monotonic() > end:
                break
            time.sleep(0.2)
        done = Outcome("onboard-done", "http", str(state), time.monotonic() - t, t, state == "succeeded", "" if state == "succeeded" else f"{oid}: {r.status} {r.body!r}"[:300])
        if state != "succeeded":
            return [done]
        td = time.monotonic()
        d = http_call(self.http, "DELETE", f"/v1/objects/{oid}", timeout=self.timeout)
        return [done, outcome("delete", "http", d, td, frozenset({"204"}), f"{oid}: {d.status} {d.body!r}"[:300])]

    def _follow_grpc(self, oid: str, op: str, t: float) -> List[Outcome]:
        end = t + self.timeout * 4
        while True:
            r = grpc_call(lambda: self.client.get_operation(op))
            state = r.body.state if r.status == "OK" else None
            if state != "RUNNING" or time.monotonic() > end:
                break
            time.sleep(0.2)
        ok = state == "SUCCEEDED"
        done = Outcome("onboard-done", "grpc", str(state), time.monotonic() - t, t, ok, "" if ok else f"{oid}: {r.status} {r.detail} {r.body!r}"[:300])
        if not ok:
            return [done]
        td = time.monotonic()
        d = grpc_call(lambda: self.client.delete_object(oid))
        return [done, outcome("delete", "grpc", d, td, frozenset({"OK"}), oid)]
