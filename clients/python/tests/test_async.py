"""The asyncio client: a burst of estimates that waits in the server's queue; concurrent
estimates against a server that runs one at a time and queues none, so that
RESOURCE_EXHAUSTED really happens and is retried after the server's wait; and the other
calls."""

from __future__ import annotations

import asyncio
import logging
import re
from pathlib import Path
from typing import Iterator, List

import pytest

import b2tfpose
from conftest import SAMPLE_ID, Onboarded, Scene, assert_same_pose
from servers import Server

EXHAUSTED = 'route="/b2tfpose.v1.PoseService/Estimate",status="RESOURCE_EXHAUSTED"'
OK = 'route="/b2tfpose.v1.PoseService/Estimate",status="OK"'


def test_sixteen_concurrent_estimates_all_succeed_with_the_defaults(work: Path, store: str, onboarded: Onboarded, scene: Scene, cli_mask_pose: b2tfpose.Pose) -> None:
    """A burst larger than the server runs at once waits in its queue (--max-estimates 2,
    default --queue-depth) with the client's default retry policy: nothing fails."""
    s = Server(store, work / "burst.log", ["--max-estimates", "2"])
    try:

        async def main() -> List[b2tfpose.Estimates]:
            async with b2tfpose.AsyncClient(s.grpc_url) as c:
                det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
                return await asyncio.gather(*(c.estimate(scene.rgb, scene.K, det) for _ in range(16)))

        all_results = asyncio.run(main())
        for results in all_results:
            assert_same_pose(results[0].pose, cli_mask_pose)
        assert s.metric(OK) == 16
        # They really queued: most of them waited for a slot.
        assert s.metric("b2tf_estimate_queue_wait_seconds_count") == 16
        assert s.metric('b2tf_estimate_queue_wait_seconds_bucket{le="0.005"}') <= 4
    finally:
        s.stop()


@pytest.fixture(scope="module")
def no_queue(work: Path, store: str, onboarded: Onboarded) -> Iterator[Server]:
    """A server that runs one estimate and queues none: any two concurrent ones collide."""
    s = Server(store, work / "no-queue.log", ["--max-estimates", "1", "--queue-depth", "0"])
    yield s
    s.stop()


def test_concurrent_estimates_retry_through_429_after_the_servers_wait(no_queue: Server, scene: Scene, cli_mask_pose: b2tfpose.Pose, caplog: pytest.LogCaptureFixture) -> None:
    refused_before = no_queue.metric(EXHAUSTED)

    async def main() -> List[b2tfpose.Estimates]:
        async with b2tfpose.AsyncClient(no_queue.grpc_url, timeout=120) as c:
            det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
            return await asyncio.gather(*(c.estimate(scene.rgb, scene.K, det) for _ in range(4)))

    with caplog.at_level(logging.INFO, logger="b2tfpose"):
        all_results = asyncio.run(main())
    for results in all_results:
        assert_same_pose(results[0].pose, cli_mask_pose)
    retries = [r.getMessage() for r in caplog.records if "RESOURCE_EXHAUSTED" in r.getMessage()]
    refused = no_queue.metric(EXHAUSTED) - refused_before
    # The server really refused (its own count), and each refusal was retried after at
    # least the wait it asked for.
    assert refused >= 1 and len(retries) == refused
    for m in retries:
        waited, asked = (float(x) for x in re.findall(r"([0-9.]+) s", m))
        assert asked > 0 and asked <= waited <= asked * 1.25 + 1e-3, m


def test_without_retries_a_refusal_says_when_to_come_back(no_queue: Server, scene: Scene) -> None:
    async def main() -> List[object]:
        async with b2tfpose.AsyncClient(no_queue.address, retry=b2tfpose.NO_RETRY) as c:
            det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
            return await asyncio.gather(*(c.estimate(scene.rgb, scene.K, det) for _ in range(4)), return_exceptions=True)

    outcomes = asyncio.run(main())
    errors = [o for o in outcomes if isinstance(o, Exception)]
    assert errors and all(isinstance(e, b2tfpose.ResourceExhausted) for e in errors)
    for e in errors:
        assert isinstance(e, b2tfpose.RpcError) and "--queue-depth" in e.message and e.code.name == "RESOURCE_EXHAUSTED"
        assert e.retry_after is not None and e.retry_after > 0
    assert any(isinstance(o, b2tfpose.Estimates) for o in outcomes)


def test_async_onboard_objects_and_health(server: Server, onboarded: Onboarded, sample_obj: Path) -> None:
    async def main() -> None:
        async with b2tfpose.AsyncClient(server.address) as c:
            await c.wait_ready(timeout=10)
            assert await c.health() == "SERVING"
            assert await c.get_object(SAMPLE_ID) == onboarded.info
            seen: List[b2tfpose.OperationStatus] = []
            info = await c.onboard("async-box", sample_obj, units="m", level=0, in_plane=1, progress=seen.append, replace=True, retry=True)
            assert info.templates == 12 and seen[-1].state == "SUCCEEDED"
            assert "async-box" in [o.id for o in await c.list_objects()]
            op = await c.onboard("async-big", sample_obj, units="m", level=3, wait=False, retry=True)
            assert isinstance(op, b2tfpose.AsyncOperation) and (await op.status()).state == "RUNNING"
            await op.cancel()
            with pytest.raises(b2tfpose.OperationCancelled):
                await op.wait(timeout=60)
            await c.delete_object("async-box")
            with pytest.raises(b2tfpose.NotFound):
                await c.get_object("async-box")

    asyncio.run(main())
