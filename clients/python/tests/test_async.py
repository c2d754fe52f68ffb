"""The asyncio client: eight concurrent estimates against a server that runs one at a
time, so that RESOURCE_EXHAUSTED really happens and is retried; and the other calls."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import List

import pytest

import b2tfpose
from conftest import SAMPLE_ID, Onboarded, Scene, assert_same_pose
from servers import Server

EXHAUSTED = 'route="/b2tfpose.v1.PoseService/Estimate",status="RESOURCE_EXHAUSTED"'
OK = 'route="/b2tfpose.v1.PoseService/Estimate",status="OK"'


def test_eight_concurrent_estimates_retry_through_429(server: Server, onboarded: Onboarded, scene: Scene, cli_mask_pose: b2tfpose.Pose, caplog: pytest.LogCaptureFixture) -> None:
    refused_before = server.metric(EXHAUSTED)
    ok_before = server.metric(OK)
    policy = b2tfpose.RetryPolicy(max_attempts=100, initial_backoff=0.05, max_backoff=0.5)

    async def main() -> List[b2tfpose.Estimates]:
        async with b2tfpose.AsyncClient(server.grpc_url, retry=policy, timeout=120) as c:
            det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
            return await asyncio.gather(*(c.estimate(scene.rgb, scene.K, det) for _ in range(8)))

    with caplog.at_level(logging.INFO, logger="b2tfpose"):
        all_results = asyncio.run(main())
    assert len(all_results) == 8
    for results in all_results:
        assert results[0].pose is not None
        assert_same_pose(results[0].pose, cli_mask_pose)
    retries = [r for r in caplog.records if "RESOURCE_EXHAUSTED" in r.getMessage()]
    refused = server.metric(EXHAUSTED) - refused_before
    # The server really refused (its own count), and each refusal was retried.
    assert refused >= 1 and len(retries) == refused
    assert server.metric(OK) - ok_before == 8


def test_without_retries_concurrent_estimates_meet_resource_exhausted(server: Server, onboarded: Onboarded, scene: Scene) -> None:
    async def main() -> List[object]:
        async with b2tfpose.AsyncClient(server.address, retry=b2tfpose.NO_RETRY) as c:
            det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
            return await asyncio.gather(*(c.estimate(scene.rgb, scene.K, det) for _ in range(4)), return_exceptions=True)

    outcomes = asyncio.run(main())
    errors = [o for o in outcomes if isinstance(o, Exception)]
    assert errors and all(isinstance(e, b2tfpose.ResourceExhausted) for e in errors)
    assert all(isinstance(e, b2tfpose.RpcError) and e.message and e.code.name == "RESOURCE_EXHAUSTED" for e in errors)
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
