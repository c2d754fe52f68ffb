"""Detection through the client: the server finds the sample with no mask and no box, its
detections go back into estimate as they are, estimate by object id alone, "nothing found"
is an answer, and bad input is refused (by the client before sending, or by the server)."""

from __future__ import annotations

import asyncio
from typing import Sequence

import cv2
import numpy as np
import pytest

import b2tfpose
from conftest import SAMPLE_ID, Onboarded, Scene
from servers import Server

EVERY = dict(min_score=0.0, max_detections=3)  # every candidate kept: what the search reaches


def box_iou(a: Sequence[float], b: Sequence[float]) -> float:
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def truth_box(scene: Scene) -> Sequence[float]:
    ys, xs = np.nonzero(scene.mask)
    return (float(xs.min()), float(ys.min()), float(xs.max() - xs.min() + 1), float(ys.max() - ys.min() + 1))


def test_detect_finds_the_object_with_its_mask_and_coarse_pose(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    found = client.detect(scene.rgb, scene.K, [SAMPLE_ID], **EVERY)
    assert 1 <= len(found) <= 3 and found.reason is None and found.total_ms > 0 and "total" in found.timings_ms
    assert found.searched[0]["object_id"] == SAMPLE_ID and found.searched[0]["scales"] >= 1
    for d in found:
        assert isinstance(d, b2tfpose.Detection) and d.object_id == SAMPLE_ID and 0.0 <= d.score <= 1.0
        assert d.mask_array().shape == (240, 320) and d.mask_array().any()
        assert d.coarse_pose is not None and d.mask_source in ("silhouette", "graph_cut")
        # The score is its terms combined (docs/detection.md): they all came through.
        c = 0.5 if d.colour_score is None else d.colour_score
        t = 0.5 if d.texture_score is None else d.texture_score
        assert abs(d.score - d.outline_score * c * (0.5 + 0.5 * t)) < 1e-4
    assert max(box_iou(d.box, truth_box(scene)) for d in found if d.box is not None) >= 0.5


def test_detect_with_depth_finds_the_surface_of_the_objects_size(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    # The render's depth PNG: uint16 tenths of a millimetre, 0 off the object.
    depth = cv2.imread(str(scene.dir / "depth.png"), cv2.IMREAD_ANYDEPTH)
    found = client.detect(scene.rgb, scene.K, [SAMPLE_ID], depth=depth, depth_scale=0.1)
    assert len(found) == 1 and found[0].mask_source == "depth_segment"
    assert found[0].box is not None and box_iou(found[0].box, truth_box(scene)) > 0.9
    # A distance range that holds nothing: an answer with the reason.
    none = client.detect(scene.rgb, scene.K, [SAMPLE_ID], depth=depth, depth_scale=0.1, min_distance=5.0)
    assert len(none) == 0 and "distance range" in (none.reason or "")
    with pytest.raises(ValueError, match="depth_scale without depth"):
        client.detect(scene.rgb, scene.K, [SAMPLE_ID], depth_scale=0.1)


def test_detections_go_back_into_estimate_and_estimate_by_id(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    found = client.detect(scene.rgb, scene.K, None, **EVERY)  # None: every stored object
    [r] = client.estimate(scene.rgb, scene.K, found[:1], rrc=False)
    assert r.ok and r.detection_index == 0 and r.confirmation_score is None
    results = client.estimate(scene.rgb, scene.K, objects=[SAMPLE_ID], rrc=False, **EVERY)
    assert results.detections and results.reason is None
    best = results.best(SAMPLE_ID)
    assert best is not None and best.detection_index is not None and best.detection_index < len(results.detections)
    # Confirmed at its estimated pose by the server's detector.
    assert best.confirmation_score is not None and 0.0 <= best.confirmation_score <= 1.0


def test_nothing_found_is_an_answer_with_a_reason(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    blank = np.full((240, 320, 3), 90, np.uint8)
    found = client.detect(blank, scene.K, [SAMPLE_ID])
    assert list(found) == [] and found.reason
    results = client.estimate(blank, scene.K, objects=[SAMPLE_ID])
    assert list(results) == [] and results.reason and results.detections == []


def test_bad_detect_inputs_are_refused(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
    with pytest.raises(ValueError, match="not both"):
        client.estimate(scene.rgb, scene.K, det, objects=[SAMPLE_ID])
    with pytest.raises(ValueError, match="or name objects"):
        client.estimate(scene.rgb, scene.K)
    with pytest.raises(TypeError, match="objects"):
        client.detect(scene.rgb, scene.K, SAMPLE_ID)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="min_score"):
        client.detect(scene.rgb, scene.K, [SAMPLE_ID], min_score=2.0)
    with pytest.raises(ValueError, match="max_detections"):
        client.detect(scene.rgb, scene.K, [SAMPLE_ID], max_detections=0)
    with pytest.raises(b2tfpose.NotFound, match="nope"):
        client.detect(scene.rgb, scene.K, ["nope"])
    with pytest.raises(b2tfpose.InvalidArgument, match="min_distance_m"):
        client.detect(scene.rgb, scene.K, [SAMPLE_ID], min_distance=2.0, max_distance=1.0)
    with pytest.raises(b2tfpose.InvalidArgument, match="over the limit"):
        client.detect(scene.rgb, scene.K, [f"o{i}" for i in range(65)])


def test_async_detect(server: Server, onboarded: Onboarded, scene: Scene) -> None:
    async def main() -> b2tfpose.Detections:
        async with b2tfpose.AsyncClient(server.grpc_url, timeout=120) as c:
            return await c.detect(scene.rgb, scene.K, [SAMPLE_ID], **EVERY)

    found = asyncio.run(main())
    assert found and all(d.object_id == SAMPLE_ID for d in found)


def test_tracking_starts_from_a_detection(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> None:
    results = list(client.track([scene.rgb, scene.rgb], K=scene.K, objects=[SAMPLE_ID], min_score=0.0, max_detections=1))
    assert [len(r.objects) for r in results] == [1, 1]
    assert results[0].objects[0].mode == "estimated" and results[0].objects[0].pose is not None
    assert results[1].objects[0].mode == "tracked"
    with pytest.raises(ValueError, match="not both"):
        list(client.track([b2tfpose.TrackFrame(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)], objects=[SAMPLE_ID])]))
