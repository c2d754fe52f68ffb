"""Every exception class from a real failing call against the real server, and the retry
policy's schedule."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path
from typing import List

import grpc
import pytest

import b2tfpose
from b2tfpose.errors import error_class
from conftest import SAMPLE_ID, Onboarded, Scene
from servers import Server

DEGENERATE_OBJ = b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n"  # loads, renders empty


def test_invalid_argument_names_the_field(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    with pytest.raises(b2tfpose.InvalidArgument) as e:
        client.estimate(scene.rgb, (-500.0, 500.0, 159.5, 119.5), [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
    assert "intrinsics" in e.value.message and e.value.code == grpc.StatusCode.INVALID_ARGUMENT and e.value.method == "Estimate"
    with pytest.raises(b2tfpose.InvalidArgument, match="object id"):
        client.onboard("bad/id", DEGENERATE_OBJ, format="obj", units="m")
    with pytest.raises(b2tfpose.InvalidArgument, match="non-finite"):
        client.onboard("nan-mesh", b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", format="obj", units="m")


def test_not_found(client: b2tfpose.Client, scene: Scene) -> None:
    with pytest.raises(b2tfpose.NotFound, match="no-such-object") as e:
        client.get_object("no-such-object")
    # The server's id of the call, to find its log lines.
    rid = e.value.request_id
    assert rid and len(rid) == 32 and all(c in "0123456789abcdef" for c in rid) and rid in str(e.value)
    # One the caller chose is used instead; a malformed one is refused before sending.
    with b2tfpose.request_id("job-17.frame:3"), pytest.raises(b2tfpose.NotFound) as e:
        client.get_object("no-such-object")
    assert e.value.request_id == "job-17.frame:3"
    with pytest.raises(ValueError, match="request id"), b2tfpose.request_id("two words"):
        pass
    with pytest.raises(b2tfpose.NotFound):
        client.estimate(scene.rgb, scene.K, [b2tfpose.Detection("no-such-object", mask=scene.mask)])
    with pytest.raises(b2tfpose.NotFound):
        client.get_operation("op-does-not-exist")


def test_already_exists(client: b2tfpose.Client, onboarded: Onboarded, sample_obj: Path) -> None:
    with pytest.raises(b2tfpose.AlreadyExists, match=SAMPLE_ID):
        client.onboard(SAMPLE_ID, sample_obj, units="m", level=0)


def test_resource_exhausted_without_retries(client: b2tfpose.Client, sample_obj: Path) -> None:
    # One onboarding at a time: a second one is refused at once.
    op = client.onboard("slow-box", sample_obj, units="m", level=3, wait=False, replace=True, retry=True)
    try:
        with pytest.raises(b2tfpose.ResourceExhausted):
            client.onboard("other-box", sample_obj, units="m", level=0)
    finally:
        op.cancel()
        with pytest.raises(b2tfpose.OperationCancelled):
            op.wait(timeout=60)


def test_deadline_exceeded(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    with pytest.raises(b2tfpose.DeadlineExceeded):
        client.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)], timeout=0.05)


def test_unavailable_and_its_retries() -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with b2tfpose.Client(f"127.0.0.1:{port}", timeout=5, retry=b2tfpose.NO_RETRY) as c:
        with pytest.raises(b2tfpose.Unavailable):
            c.list_objects()
    delays: List[float] = []
    policy = b2tfpose.RetryPolicy(max_attempts=3, initial_backoff=0.01, max_backoff=0.02)
    with b2tfpose.Client(f"127.0.0.1:{port}", timeout=5, retry=policy) as c:
        import logging

        class Grab(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                delays.append(float(record.getMessage().rsplit(" ", 2)[-2]))

        h = Grab()
        logging.getLogger("b2tfpose").addHandler(h)
        logging.getLogger("b2tfpose").setLevel(logging.INFO)
        try:
            with pytest.raises(b2tfpose.Unavailable):
                c.list_objects()
            # Delete is not idempotent: not retried unless asked.
            n = len(delays)
            with pytest.raises(b2tfpose.Unavailable):
                c.delete_object("x")
            assert len(delays) == n
            with pytest.raises(b2tfpose.Unavailable):
                c.delete_object("x", retry=True)
        finally:
            logging.getLogger("b2tfpose").removeHandler(h)
    assert len(delays) == 4 and all(0 <= d <= 0.02 for d in delays)


def test_retries_stop_at_the_time_budget() -> None:
    import time

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    policy = b2tfpose.RetryPolicy(budget=0.3, initial_backoff=0.02, max_backoff=0.05)
    with b2tfpose.Client(f"127.0.0.1:{port}", timeout=30, retry=policy) as c:
        t0 = time.monotonic()
        with pytest.raises(b2tfpose.Unavailable):
            c.list_objects()
        # Retried until the budget ran out, far before the call's own deadline.
        assert time.monotonic() - t0 < 5


def test_unauthenticated(work: Path, store: str, onboarded: Onboarded) -> None:
    keys = work / "keys.txt"
    keys.write_text("# test keys\nk-123\nk-reader scopes=read name=reader\n")
    s = Server(store, work / "keyed.log", ["--api-keys-file", str(keys)])
    try:
        with b2tfpose.Client(s.address) as c:
            c.wait_ready(timeout=30)  # the health check is open without a key; SERVING a moment after /readyz
            assert c.health() == "SERVING"
            with pytest.raises(b2tfpose.Unauthenticated):
                c.list_objects()
        with b2tfpose.Client(s.address, api_key="wrong") as c, pytest.raises(b2tfpose.Unauthenticated):
            c.get_object(SAMPLE_ID)
        with b2tfpose.Client(s.address, api_key="k-123") as c:
            assert c.get_object(SAMPLE_ID).id == SAMPLE_ID
        with b2tfpose.Client(s.address, api_key="k-reader") as c:
            assert c.get_object(SAMPLE_ID).id == SAMPLE_ID  # the read scope reads
            with pytest.raises(b2tfpose.PermissionDenied, match="`write` scope"):
                c.delete_object(SAMPLE_ID)

        async def aio() -> None:
            async with b2tfpose.AsyncClient(s.address, api_key="nope") as c:
                with pytest.raises(b2tfpose.Unauthenticated):
                    await c.list_objects()

        asyncio.run(aio())
    finally:
        s.stop()


def test_permission_denied_on_a_read_only_replica(work: Path, store: str, onboarded: Onboarded, sample_obj: Path) -> None:
    s = Server(store, work / "read-only.log", ["--read-only"])
    try:
        with b2tfpose.Client(s.address) as c:
            assert c.get_object(SAMPLE_ID).id == SAMPLE_ID  # reads are served
            with pytest.raises(b2tfpose.PermissionDenied, match="read-only"):
                c.onboard("never", sample_obj, units="m", level=0, in_plane=1)
            with pytest.raises(b2tfpose.PermissionDenied, match="read-only"):
                c.delete_object(SAMPLE_ID)
            assert c.get_object(SAMPLE_ID).id == SAMPLE_ID
    finally:
        s.stop()


def test_internal_from_a_damaged_object(client: b2tfpose.Client, sample_obj: Path, work: Path, scene: Scene) -> None:
    client.onboard("damaged-box", sample_obj, units="m", level=0, in_plane=1, replace=True, retry=True)
    tensors = work / "store" / "damaged-box" / "tensors.safetensors"  # the dir:// store's layout
    tensors.write_bytes(tensors.read_bytes()[:1000])
    try:
        with pytest.raises(b2tfpose.Internal, match="damaged"):
            client.estimate(scene.rgb, scene.K, [b2tfpose.Detection("damaged-box", mask=scene.mask)])
    finally:
        client.delete_object("damaged-box")


def test_operation_failed(client: b2tfpose.Client) -> None:
    with pytest.raises(b2tfpose.OperationFailed) as e:
        client.onboard("degenerate", DEGENERATE_OBJ, format="obj", units="m", level=0, in_plane=1, retry=True)
    assert not isinstance(e.value, b2tfpose.OperationCancelled)
    assert e.value.status.state == "FAILED" and e.value.status.error and "empty" in e.value.status.error


def test_hierarchy_and_mapping() -> None:
    classes = [
        b2tfpose.InvalidArgument,
        b2tfpose.NotFound,
        b2tfpose.PermissionDenied,
        b2tfpose.AlreadyExists,
        b2tfpose.Unauthenticated,
        b2tfpose.ResourceExhausted,
        b2tfpose.DeadlineExceeded,
        b2tfpose.Unavailable,
        b2tfpose.Internal,
    ]
    for cls in classes:
        assert issubclass(cls, b2tfpose.RpcError) and issubclass(cls, b2tfpose.B2TFPoseError)
    assert issubclass(b2tfpose.OperationCancelled, b2tfpose.OperationFailed) and issubclass(b2tfpose.OperationFailed, b2tfpose.B2TFPoseError)
    assert error_class(grpc.StatusCode.INTERNAL) is b2tfpose.Internal
    assert error_class(grpc.StatusCode.PERMISSION_DENIED) is b2tfpose.PermissionDenied
    assert error_class(grpc.StatusCode.DATA_LOSS) is b2tfpose.RpcError  # never sent by the service


def test_retry_schedule() -> None:
    import random

    p = b2tfpose.RetryPolicy(max_attempts=4, initial_backoff=0.1, max_backoff=0.3, multiplier=2)
    rng = random.Random(1)
    caps = [0.1, 0.2, 0.3, 0.3]
    for n, cap in enumerate(caps, start=1):
        samples = [p.backoff(n, rng) for _ in range(200)]
        assert all(0 <= s <= cap for s in samples) and max(samples) > cap * 0.8  # full jitter up to the cap
    assert p.should_retry(grpc.StatusCode.RESOURCE_EXHAUSTED, 3) and not p.should_retry(grpc.StatusCode.RESOURCE_EXHAUSTED, 4)
    assert not p.should_retry(grpc.StatusCode.INVALID_ARGUMENT, 1)
    # The server's wait wins over the backoff: that long, plus up to a quarter more.
    hinted = [p.backoff(1, rng, hint=2.0) for _ in range(200)]
    assert all(2.0 <= h <= 2.5 for h in hinted) and max(hinted) > 2.4
    # The default is a time budget, not a count of attempts.
    d = b2tfpose.RetryPolicy()
    assert d.max_attempts is None and d.budget == 30.0 and d.should_retry(grpc.StatusCode.RESOURCE_EXHAUSTED, 1000)
    for bad in (dict(max_attempts=0), dict(budget=-1.0), dict(hint_jitter=-0.1), dict(multiplier=0.5)):
        with pytest.raises(ValueError):
            b2tfpose.RetryPolicy(**bad)  # type: ignore[arg-type]
