"""Tracking through the client (the Track stream) against the real server: a short rendered
video of the sample moving then still, its first frame started from a mask; poses compared
with the truth and with estimate's; bad frames answered without ending the stream (or
raised); the asyncio client giving the same answers; and, on a server with one session at
most and a two-second idle timeout, the session limit, the opening retried through it, and
an idle stream ended."""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from pathlib import Path
from typing import Any, AsyncIterator, Iterator, List

import numpy as np
import pytest

import b2tfpose
from conftest import SAMPLE_ID, Onboarded, Scene, assert_same_pose
from servers import Server


def first_frame(scene: Scene) -> b2tfpose.TrackFrame:
    return b2tfpose.TrackFrame(scene.rgb, detections=[b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])


@pytest.fixture(scope="module")
def tracked(client: b2tfpose.Client, onboarded: Onboarded, video: List[Scene]) -> List[b2tfpose.TrackResult]:
    frames = [first_frame(video[0]), *(s.rgb for s in video[1:])]
    return list(client.track(frames, K=video[0].K))


def test_a_moving_then_still_object_is_estimated_then_tracked(tracked: List[b2tfpose.TrackResult], video: List[Scene], cli_mask_pose: b2tfpose.Pose) -> None:
    assert len(tracked) == len(video)
    assert [r.frame_index for r in tracked] == list(range(len(video)))
    assert all(r.ok and r.error is None and len(r.objects) == 1 for r in tracked)
    assert tracked[0].session_id and len({r.session_id for r in tracked}) == 1
    modes = [r.objects[0].mode for r in tracked]
    assert modes == [b2tfpose.TrackMode.ESTIMATED] + [b2tfpose.TrackMode.TRACKED] * (len(video) - 1), modes
    assert modes[1] == "tracked" and str(modes[0]) == "estimated"  # a str enum
    first = tracked[0].objects[0]
    assert first.track_id == 0 and first.object_id == SAMPLE_ID and first.detection_index == 0 and first.quality == 1.0 and first.reason is None
    # The first frame's full estimate is estimate's on the same image and mask.
    assert first.pose is not None
    assert_same_pose(first.pose, cli_mask_pose)
    for r, s in zip(tracked, video):
        o = r.best(SAMPLE_ID)
        assert o is not None and o.pose is not None and o.track_id == 0 and r.total_ms > 0 and o.ms > 0
        assert o.pose.rotation_error_deg(s.truth) < 3.0 and o.pose.translation_error_m(s.truth) < 0.005, (r.frame_index, o)
    for r in tracked[1:]:
        assert r.objects[0].detection_index is None and r.objects[0].quality > 0.5
        t = r.objects[0].timings_ms  # the tracking step's stages, within its total
        assert 0 < t["contour"] <= t["total"] and set(t) == {"colours", "contour", "photometric", "depth", "relearn", "total"}, t
    assert tracked[0].objects[0].timings_ms == {}  # a full estimate: no tracking step
    # Still: the pose stays put.
    still = [r.objects[0].pose for r in tracked[-3:]]
    assert all(p is not None and still[0] is not None and p.rotation_error_deg(still[0]) < 0.5 and p.translation_error_m(still[0]) < 0.001 for p in still)
    # Each result carries its frame, as sent (K from the call).
    f0, f5 = tracked[0].frame, tracked[-1].frame
    assert f0 is not None and len(f0.detections) == 1 and f5 is not None and f5.detections == () and f5.K is video[0].K and isinstance(f5.image, np.ndarray)


def test_tracked_poses_agree_with_estimate(client: b2tfpose.Client, tracked: List[b2tfpose.TrackResult], video: List[Scene]) -> None:
    s = video[3]
    [r] = client.estimate(s.rgb, s.K, [b2tfpose.Detection(SAMPLE_ID, mask=s.mask)])
    p = tracked[3].objects[0].pose
    assert r.pose is not None and p is not None
    assert p.rotation_error_deg(r.pose) < 1.0 and p.translation_error_m(r.pose) < 0.003


def test_bad_frames_are_answered_and_the_stream_goes_on(client: b2tfpose.Client, onboarded: Onboarded, video: List[Scene]) -> None:
    s0, s1 = video[0], video[1]
    fx, fy, cx, cy = s0.K[0, 0], s0.K[1, 1], s0.K[0, 2], s0.K[1, 2]
    frames = [
        b2tfpose.TrackFrame(s0.rgb, s0.K, [b2tfpose.Detection(SAMPLE_ID, mask=s0.mask)], frame_index=10),
        {"image": s1.rgb, "K": s1.K, "frame_index": 5},  # out of order
        (s1.rgb, s1.K, [{"object_id": "no-such-object", "bbox": s1.box}]),  # unknown object
        (s1.rgb, (-fx, fy, cx, cy)),  # bad intrinsics
        (s1.rgb, s1.K),  # the next: 11
    ]
    results = list(client.track(frames, raise_errors=False))
    assert len(results) == 5
    ok0, late, unknown, bad_k, ok1 = results
    assert ok0.ok and ok0.frame_index == 10 and ok0.objects[0].mode == "estimated"
    assert isinstance(late.error, b2tfpose.InvalidArgument) and "frame_index 5" in late.error.message and not late.ok
    assert late.frame_index == 5 and late.objects == [] and late.error.method == "Track" and late.error.code.name == "INVALID_ARGUMENT"
    assert isinstance(unknown.error, b2tfpose.NotFound) and "no-such-object" in unknown.error.message and unknown.frame_index is None
    assert isinstance(bad_k.error, b2tfpose.InvalidArgument) and "intrinsics" in bad_k.error.message
    # The session is as it was: the track goes on from frame 10.
    assert ok1.ok and ok1.frame_index == 11 and ok1.objects[0].mode == "tracked" and ok1.objects[0].track_id == 0
    assert len({r.session_id for r in results}) == 1


def test_depth_frames_fit_the_track_to_the_measured_surface(client: b2tfpose.Client, onboarded: Onboarded, video: List[Scene]) -> None:
    import cv2

    # Each frame's rendered depth PNG (uint16 tenths of a millimetre), as an array, as float
    # metres (in a dict frame) and as the file.
    depth = [cv2.imread(str(s.dir / "depth.png"), cv2.IMREAD_ANYDEPTH) for s in video]
    frames: List[Any] = [b2tfpose.TrackFrame(video[0].rgb, detections=[b2tfpose.Detection(SAMPLE_ID, mask=video[0].mask)], depth=depth[0], depth_scale=0.1)]
    frames.append({"image": video[1].rgb, "depth": depth[1].astype(np.float32) / 10000.0})
    frames.append(b2tfpose.TrackFrame(video[2].rgb, depth=video[2].dir / "depth.png", depth_scale=0.1))
    frames.extend(b2tfpose.TrackFrame(s.rgb, depth=d, depth_scale=0.1) for s, d in zip(video[3:], depth[3:]))
    results = list(client.track(frames, K=video[0].K))
    assert [r.objects[0].mode for r in results] == [b2tfpose.TrackMode.ESTIMATED] + [b2tfpose.TrackMode.TRACKED] * (len(video) - 1)
    for r, s in zip(results[1:], video[1:]):
        o = r.objects[0]
        assert o.pose is not None and o.pose.translation_error_m(s.truth) < 0.005, (r.frame_index, o)
        assert o.depth_fit is not None and o.depth_fit.inlier_share > 0.8 and o.depth_fit.rms_mm < 3.0, o.depth_fit
    assert results[0].objects[0].depth_fit is None  # a full estimate, not a tracked frame
    # Bad depth: refused in the client where it can tell, by the server otherwise (the
    # stream goes on with raise_errors=False).
    with pytest.raises(ValueError, match="depth_scale is needed with uint16 depth"):
        next(client.track([b2tfpose.TrackFrame(video[0].rgb, depth=depth[0])], K=video[0].K))
    with pytest.raises(ValueError, match="must be registered to the colour image"):
        next(client.track([b2tfpose.TrackFrame(video[0].rgb, depth=depth[0][:100], depth_scale=0.1)], K=video[0].K))
    with pytest.raises(ValueError, match="depth_scale without depth"):
        next(client.track([b2tfpose.TrackFrame(video[0].rgb, depth_scale=0.1)], K=video[0].K))
    [bad] = client.track([b2tfpose.TrackFrame(video[0].rgb, depth=depth[0], depth_scale=100.0)], K=video[0].K, raise_errors=False)
    assert isinstance(bad.error, b2tfpose.InvalidArgument) and "outside 0.05–20 m" in bad.error.message, bad.error


def test_a_bad_frame_raises_by_default(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    seen: List[b2tfpose.TrackResult] = []
    # No detection: nothing tracked, nothing estimated (cheap); then an unknown object.
    frames = [(scene.rgb, scene.K), (scene.rgb, scene.K, [b2tfpose.Detection("no-such-object", mask=scene.mask)]), (scene.rgb, scene.K)]
    with pytest.raises(b2tfpose.NotFound, match="no-such-object"):
        for r in client.track(frames):
            seen.append(r)
    assert len(seen) == 1 and seen[0].objects == [] and seen[0].frame_index == 0


def test_inputs_checked_before_sending(client: b2tfpose.Client, scene: Scene) -> None:
    with pytest.raises(ValueError, match="max_tracks"):
        client.track([], max_tracks=0)
    with pytest.raises(ValueError, match="lost_below"):
        client.track([], lost_below=1.5)
    with pytest.raises(ValueError, match="prefetch"):
        client.track([], prefetch=9)
    with pytest.raises(ValueError, match="without K"):
        next(client.track([scene.rgb]))
    with pytest.raises(ValueError, match="tuple"):
        next(client.track([(scene.rgb,)], K=scene.K))
    with pytest.raises(TypeError, match="frame"):
        next(client.track([42], K=scene.K))  # type: ignore[list-item]
    with pytest.raises(ValueError, match="frame_index"):
        next(client.track([b2tfpose.TrackFrame(scene.rgb, frame_index=-1)], K=scene.K))
    # The server checks the options at opening (max_tracks is 1-32): the stream is refused.
    with pytest.raises(b2tfpose.InvalidArgument, match="max_tracks"):
        next(client.track([scene.rgb], K=scene.K, max_tracks=33))
    assert list(client.track([])) == []


def test_async_client_tracks_the_same(server: Server, tracked: List[b2tfpose.TrackResult], video: List[Scene]) -> None:
    async def frames() -> AsyncIterator[Any]:
        yield first_frame(video[0])
        for s in video[1:4]:
            await asyncio.sleep(0)
            yield s.rgb

    async def main() -> List[b2tfpose.TrackResult]:
        async with b2tfpose.AsyncClient(server.address) as c:
            out = [r async for r in c.track(frames(), K=video[0].K, prefetch=2)]
            # A bad frame raises (the default); plain iterables are taken too.
            with pytest.raises(b2tfpose.InvalidArgument, match="intrinsics"):
                async for _ in c.track([(video[0].rgb, (-500.0, 500.0, 159.5, 119.5))]):
                    pass
            return out

    results = asyncio.run(main())
    assert [r.frame_index for r in results] == [0, 1, 2, 3]
    for a, b in zip(results, tracked):
        assert a.objects[0].mode == b.objects[0].mode and a.session_id != b.session_id
        pa, pb_ = a.objects[0].pose, b.objects[0].pose
        assert pa is not None and pb_ is not None
        assert_same_pose(pa, pb_, rot_deg=0.01, trans_m=1e-5)


@pytest.fixture(scope="module")
def track_server(work: Path, store: str, onboarded: Onboarded) -> Iterator[Server]:
    s = Server(store, work / "track-server.log", ["--max-track-sessions", "1", "--track-idle-timeout-s", "2"])
    yield s
    s.stop()


def test_session_limit_retried_opening_and_idle_stream(track_server: Server, scene: Scene, caplog: pytest.LogCaptureFixture) -> None:
    async def frames() -> AsyncIterator[np.ndarray]:
        yield scene.rgb
        yield scene.rgb  # taken only when asked for (prefetch=0)

    async def main() -> None:
        async with b2tfpose.AsyncClient(track_server.address) as ac:
            first = ac.track(frames(), K=scene.K, prefetch=0)
            r = await first.__anext__()  # the one session is open, then idle
            assert r.ok and r.objects == [] and r.session_id in track_server.get("/v1/tracks")
            with b2tfpose.Client(track_server.address, timeout=30) as c:
                with pytest.raises(b2tfpose.ResourceExhausted, match="limit"):
                    next(c.track([scene.rgb], K=scene.K, retry=False))
                # Retried at opening until the server ends the idle stream (2 s).
                policy = b2tfpose.RetryPolicy(max_attempts=100, initial_backoff=0.05, max_backoff=0.2)
                with caplog.at_level(logging.INFO, logger="b2tfpose"):
                    [second] = list(c.track([scene.rgb], K=scene.K, retry=policy, timeout=20))
                assert second.ok and second.frame_index == 0 and second.session_id != r.session_id
                assert any("Track failed with RESOURCE_EXHAUSTED" in rec.getMessage() for rec in caplog.records)
            # The idle stream's next frame meets its end: the server's status, not the write's.
            with pytest.raises(b2tfpose.DeadlineExceeded, match="no frame"):
                await first.__anext__()

    asyncio.run(main())


def test_leaving_early_ends_the_stream(track_server: Server, scene: Scene) -> None:
    with b2tfpose.Client(track_server.address, timeout=30) as c:
        endless = c.track(itertools.repeat(scene.rgb), K=scene.K)
        for n, r in enumerate(endless):
            assert r.ok and r.frame_index == n
            if n == 2:
                break
        endless.close()  # what leaving the loop does once nothing refers to the iterator
        end = time.monotonic() + 10
        while '"sessions":[]' not in track_server.get("/v1/tracks").replace(" ", ""):
            assert time.monotonic() < end, "the stream's session outlived it"
            time.sleep(0.05)
        assert [r.frame_index for r in c.track([scene.rgb] * 3, K=scene.K, retry=False)] == [0, 1, 2]
