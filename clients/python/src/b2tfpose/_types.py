"""The typed results of the calls, and their parsing from the protobuf messages (shared by
the sync and async clients)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from ._pose import Pose
from .v1 import pose_service_pb2 as pb


@dataclass(frozen=True)
class ObjectInfo:
    """An onboarded object."""

    id: str
    templates: int
    """Templates stored (viewpoints x in-plane rotations)."""
    diameter_m: float
    """Largest distance between two vertices, metres."""
    backbone: str
    bytes: int
    created_unix_s: int
    mesh_units: str
    """Unit of the uploaded mesh file; the stored model is metres."""

    @classmethod
    def from_pb(cls, m: pb.ObjectInfo) -> "ObjectInfo":
        return cls(
            id=m.id,
            templates=m.templates,
            diameter_m=m.diameter_m,
            backbone=m.backbone,
            bytes=m.bytes,
            created_unix_s=m.created_unix_s,
            mesh_units=m.mesh_units,
        )


RUNNING = "RUNNING"
SUCCEEDED = "SUCCEEDED"
FAILED = "FAILED"
CANCELLED = "CANCELLED"


@dataclass(frozen=True)
class OperationStatus:
    """One state of an onboarding: ``state`` is RUNNING, SUCCEEDED, FAILED or CANCELLED."""

    id: str
    object_id: str
    state: str
    templates_done: int
    templates_total: int
    error: Optional[str] = None
    object: Optional[ObjectInfo] = None

    @property
    def done(self) -> bool:
        """Finished (succeeded, failed or cancelled)."""
        return self.state in (SUCCEEDED, FAILED, CANCELLED)

    @property
    def fraction(self) -> float:
        """Progress in [0, 1]."""
        return self.templates_done / self.templates_total if self.templates_total else 0.0

    @classmethod
    def from_pb(cls, m: pb.Operation) -> "OperationStatus":
        return cls(
            id=m.id,
            object_id=m.object_id,
            state=pb.Operation.State.Name(m.state),
            templates_done=m.templates_done,
            templates_total=m.templates_total,
            error=m.error or None,
            object=ObjectInfo.from_pb(m.object) if m.HasField("object") else None,
        )


@dataclass(frozen=True)
class Result:
    """The estimate of one object instance. ``pose`` is None when none was found; then
    ``reason`` says why."""

    object_id: str
    instance: int
    """Instance number within the object, best detection first."""
    pose: Optional[Pose]
    score: float
    """Confidence in [0, 1]."""
    detection_index: Optional[int]
    """Index into the request's detections of the mask the pose came from."""
    reason: Optional[str]
    timings_ms: Dict[str, float] = field(default_factory=dict)
    """Time per pipeline stage on the server, milliseconds."""
    diagnostics: Any = None
    """The server's diagnostics document, parsed JSON: per candidate mask, retrieval,
    matches, inliers, RRC, refinement, verified hypotheses, IoU and selection scores."""

    @property
    def ok(self) -> bool:
        return self.pose is not None

    @classmethod
    def from_pb(cls, m: pb.InstanceResult) -> "Result":
        pose = None
        if m.HasField("pose"):
            if len(m.pose.r) != 9 or len(m.pose.t) != 3:
                raise ValueError(f"the server sent a pose with {len(m.pose.r)} rotation and {len(m.pose.t)} translation values")
            pose = Pose(list(m.pose.r), list(m.pose.t))
        try:
            diagnostics = json.loads(m.diagnostics_json) if m.diagnostics_json else None
        except json.JSONDecodeError:
            diagnostics = m.diagnostics_json
        return cls(
            object_id=m.object_id,
            instance=m.instance,
            pose=pose,
            score=m.score,
            detection_index=m.detection_index if m.detection_index >= 0 else None,
            reason=m.reason or None,
            timings_ms=dict(m.timings_ms),
            diagnostics=diagnostics,
        )


class Estimates(List[Result]):
    """The results of one estimate call: a list of :class:`Result` (one per instance,
    grouped by object), plus the server's ``total_ms`` for the whole request."""

    total_ms: float

    def __init__(self, results: List[Result], total_ms: float) -> None:
        super().__init__(results)
        self.total_ms = total_ms

    @classmethod
    def from_pb(cls, m: pb.EstimateResponse) -> "Estimates":
        return cls([Result.from_pb(r) for r in m.results], m.total_ms)

    def best(self, object_id: Optional[str] = None) -> Optional[Result]:
        """The highest-scoring result with a pose (of ``object_id`` if given)."""
        found = [r for r in self if r.pose is not None and (object_id is None or r.object_id == object_id)]
        return max(found, key=lambda r: r.score) if found else None
