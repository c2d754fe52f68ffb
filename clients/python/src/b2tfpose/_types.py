"""The typed results of the calls, and their parsing from the protobuf messages (shared by
the sync and async clients)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Tuple

import grpc

import numpy as np
import numpy.typing as npt

from ._convert import Detection
from ._pose import Pose
from .masks import rle_to_mask
from .errors import RpcError, error_class
from .v1 import pose_service_pb2 as pb

if TYPE_CHECKING:
    from ._convert import TrackFrame


@dataclass(frozen=True)
class ContinuousSymmetry:
    """Free rotation of the object about an axis (a cylinder's), in object coordinates."""

    axis: Tuple[float, float, float]
    """The axis' direction (not necessarily unit length)."""
    offset_m: Tuple[float, float, float]
    """A point on the axis, metres."""


@dataclass(frozen=True)
class Symmetries:
    """An object's symmetries in its own frame, as BOP's models_info.json writes them. A pose
    is as right as ``pose @ s`` for each ``s`` in ``discrete`` (see :meth:`equivalent_poses`),
    and as any turn about a ``continuous`` axis. Both empty: the object has no symmetry."""

    source: str
    """"mesh" (found by onboarding from the mesh) or "models_info" (given by the user)."""
    discrete: Tuple[Pose, ...] = ()
    """The transformations x -> R x + t of the object frame (metres) that leave it looking
    the same, the identity not included, each as a :class:`~b2tfpose.Pose`."""
    continuous: Tuple[ContinuousSymmetry, ...] = ()

    def equivalent_poses(self, pose: Pose) -> List[Pose]:
        """``pose`` and the poses its discrete symmetries make equally right."""
        return [pose] + [pose @ s for s in self.discrete]

    @classmethod
    def from_pb(cls, m: pb.Symmetries) -> "Symmetries":
        def vec3(v: Any, what: str) -> Tuple[float, float, float]:
            if len(v) != 3:
                raise ValueError(f"the server sent a continuous symmetry whose {what} has {len(v)} values")
            return (float(v[0]), float(v[1]), float(v[2]))

        for d in m.discrete:
            if len(d.matrix) != 16:
                raise ValueError(f"the server sent a discrete symmetry of {len(d.matrix)} values, not 16")
        return cls(
            source=m.source,
            discrete=tuple(Pose.from_matrix(list(d.matrix)) for d in m.discrete),
            continuous=tuple(ContinuousSymmetry(vec3(c.axis, "axis"), vec3(c.offset_m, "offset")) for c in m.continuous),
        )


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
    symmetries: Optional[Symmetries] = None
    """Found from the mesh at onboarding; None: unknown (an object stored before symmetries
    were found: re-onboard it, or ``b2tf objects upgrade``)."""

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
            symmetries=Symmetries.from_pb(m.symmetries) if m.HasField("symmetries") else None,
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


def pose_from_pb(m: pb.Pose) -> Pose:
    if len(m.r) != 9 or len(m.t) != 3:
        raise ValueError(f"the server sent a pose with {len(m.r)} rotation and {len(m.t)} translation values")
    return Pose(list(m.r), list(m.t))


@dataclass(frozen=True)
class RunnerUp:
    """A pose the evidence nearly chose instead of the answer: the best pose the server
    judged on the photo that puts the surface more than a tenth of the object's diameter
    from the answer's (up to its symmetries)."""

    pose: Pose
    margin: float
    """The answer's verification score minus this pose's (>= 0). A small one says the photo
    could not tell the two apart: look again, or act on both."""
    distance_over_diameter: float
    """The largest distance of a surface point between this pose and the answer, up to the
    symmetries, as a share of the object's diameter (above 0.1)."""
    close_call: bool = False
    """The server's verdict: the margin is below its close-call threshold (0.03; on unseen
    generated scenes the answer was right on 30 of 48 instances below it and on 185 of 192
    above, the repository's docs/benchmarks.md, "The runner-up's margin")."""

    @classmethod
    def from_pb(cls, m: pb.RunnerUp) -> "RunnerUp":
        return cls(pose=pose_from_pb(m.pose), margin=m.margin, distance_over_diameter=m.distance_over_diameter, close_call=m.close_call)


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
    """Index into the request's detections (or, when the server detected, into the
    response's ``detections``) of the mask the pose came from."""
    reason: Optional[str]
    timings_ms: Dict[str, float] = field(default_factory=dict)
    """Time per pipeline stage on the server, milliseconds."""
    confirmation_score: Optional[float] = None
    """When the server detected the object (``estimate(objects=...)``): the detector's
    evidence at this pose in [0, 1], which decided that the instance is there (it reaches
    1.22 × the request's ``min_score``, 0.55 at the default; with depth 1.11 ×, 0.5). None
    when the request gave its detections."""
    diagnostics: Any = None
    """The server's diagnostics document, parsed JSON: per candidate mask, retrieval,
    matches, inliers, RRC, refinement, verified hypotheses, IoU and selection scores."""
    symmetries: Optional[Symmetries] = None
    """The object's symmetries (None: unknown): ``symmetries.equivalent_poses(pose)`` are
    all equally right, as is any turn about a continuous axis."""
    arbitrary_rotation_about_axis: bool = False
    """The object has a continuous symmetry: the pose's rotation about that axis is
    arbitrary, any turn about it being equally right (pick the grasp you prefer)."""
    runner_up: Optional[RunnerUp] = None
    """The best pose judged on the photo that is another answer, and by how much it lost
    (None: there was none, or verification was off)."""

    @property
    def ok(self) -> bool:
        return self.pose is not None

    def close_call(self, below: Optional[float] = None) -> bool:
        """Whether another pose nearly won: the server's verdict (``runner_up.close_call``),
        or, given ``below``, whether the runner-up lost by less than that. Worth a second
        photo from elsewhere before acting on the pose."""
        if self.runner_up is None:
            return False
        return self.runner_up.close_call if below is None else self.runner_up.margin < below

    @classmethod
    def from_pb(cls, m: pb.InstanceResult) -> "Result":
        pose = pose_from_pb(m.pose) if m.HasField("pose") else None
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
            confirmation_score=m.confirmation_score if m.HasField("confirmation_score") else None,
            diagnostics=diagnostics,
            symmetries=Symmetries.from_pb(m.symmetries) if m.HasField("symmetries") else None,
            arbitrary_rotation_about_axis=m.arbitrary_rotation_about_axis,
            runner_up=RunnerUp.from_pb(m.runner_up) if m.HasField("runner_up") else None,
        )


@dataclass(frozen=True, eq=False)
class DetectedObject(Detection):
    """An object instance the server's detector found: a :class:`~b2tfpose.Detection`
    (``object_id``, ``rle``, ``box``, ``score``), so it can be passed to
    :meth:`~b2tfpose.Client.estimate` as it is, plus what the detector knows of it."""

    coarse_pose: Optional[Pose] = None
    """The matched template's pose where it was found: a coarse hypothesis (tens of
    degrees, a few per cent of depth)."""
    mask_source: str = ""
    """"silhouette" (the mesh rendered at the coarse pose), "graph_cut" (the photo
    segmented inside the box, where it agreed with the render) or "depth_segment" (a
    surface of the depth image, of the object's size: detection with depth)."""
    shape_score: float = 0.0
    """The score's terms in [0, 1]: template match, outline agreement, colour agreement
    (None for meshes without colours), interior-edge agreement (None where the render
    shows too few interior edges)."""
    outline_score: float = 0.0
    colour_score: Optional[float] = None
    texture_score: Optional[float] = None

    def mask_array(self) -> "npt.NDArray[np.bool_]":
        """The mask as a HxW bool array."""
        assert self.rle is not None
        return rle_to_mask(self.rle)

    @classmethod
    def from_pb(cls, m: pb.DetectedObject) -> "DetectedObject":
        return cls(
            object_id=m.object_id,
            rle={"counts": list(m.mask_rle.counts), "size": [m.mask_rle.height, m.mask_rle.width]},
            box=(m.bbox.x, m.bbox.y, m.bbox.width, m.bbox.height),
            score=m.score,
            coarse_pose=pose_from_pb(m.coarse_pose) if m.HasField("coarse_pose") else None,
            mask_source=m.mask_source,
            shape_score=m.shape_score,
            outline_score=m.outline_score,
            colour_score=m.colour_score if m.HasField("colour_score") else None,
            texture_score=m.texture_score if m.HasField("texture_score") else None,
        )


class Detections(List[DetectedObject]):
    """What one detect call found: a list of :class:`DetectedObject`, best first, plus
    ``reason`` (why nothing was found, when nothing was), ``timings_ms`` (the detector's
    stages), ``total_ms`` (the request on the server) and ``searched`` (per object: the
    distances and scales searched)."""

    reason: Optional[str]
    timings_ms: Dict[str, float]
    total_ms: float
    searched: List[Dict[str, Any]]

    def __init__(
        self, found: List[DetectedObject], reason: Optional[str] = None, timings_ms: Optional[Dict[str, float]] = None, total_ms: float = 0.0, searched: Optional[List[Dict[str, Any]]] = None
    ) -> None:
        super().__init__(found)
        self.reason = reason
        self.timings_ms = timings_ms or {}
        self.total_ms = total_ms
        self.searched = searched or []

    @classmethod
    def from_pb(cls, m: pb.DetectResponse) -> "Detections":
        searched = [{"object_id": s.object_id, "distance_m": (s.min_distance_m, s.max_distance_m), "scales": s.scales, "candidates": s.candidates} for s in m.searched]
        return cls([DetectedObject.from_pb(d) for d in m.detections], m.reason or None, dict(m.timings_ms), m.total_ms, searched)


class Estimates(List[Result]):
    """The results of one estimate call: a list of :class:`Result` (one per instance,
    grouped by object), plus the server's ``total_ms`` for the whole request. When the
    call named ``objects`` instead of giving detections, ``detections`` holds what the
    server's detector found (each result's ``detection_index`` points there) and
    ``reason`` says why there is no result when it found nothing. With ``overlay=True``,
    ``overlay_png`` holds the photo with the poses drawn on it (PNG bytes), else None."""

    total_ms: float
    detections: List[DetectedObject]
    reason: Optional[str]
    overlay_png: Optional[bytes]

    def __init__(self, results: List[Result], total_ms: float, detections: Optional[List[DetectedObject]] = None, reason: Optional[str] = None, overlay_png: Optional[bytes] = None) -> None:
        super().__init__(results)
        self.total_ms = total_ms
        self.detections = detections or []
        self.reason = reason
        self.overlay_png = overlay_png

    @classmethod
    def from_pb(cls, m: pb.EstimateResponse) -> "Estimates":
        return cls([Result.from_pb(r) for r in m.results], m.total_ms, [DetectedObject.from_pb(d) for d in m.detections], m.reason or None, m.overlay_png or None)

    def best(self, object_id: Optional[str] = None) -> Optional[Result]:
        """The highest-scoring result with a pose (of ``object_id`` if given)."""
        found = [r for r in self if r.pose is not None and (object_id is None or r.object_id == object_id)]
        return max(found, key=lambda r: r.score) if found else None


# ---------------------------------------------------------------------------- tracking


class TrackMode(str, Enum):
    """How a tracked object's pose in a frame came about (compares equal to its lower-case
    name, as the HTTP API writes it: ``mode == "tracked"``)."""

    ESTIMATED = "estimated"
    """A new track, from a full estimate of a detection."""
    TRACKED = "tracked"
    """Followed from the last frame."""
    REINITIALISED = "reinitialised"
    """Lost, then found again by a full estimate (of a detection over it, or searching near
    its last pose)."""
    LOST = "lost"
    """Not found in this frame (no pose)."""
    DROPPED = "dropped"
    """Lost for too long: the track ends here (no pose)."""
    REFUSED = "refused"
    """A detection that started no track (no pose; ``reason`` says why)."""
    UNSPECIFIED = "unspecified"
    """A mode this client does not know (a newer server)."""

    def __str__(self) -> str:
        return str(self.value)

    @classmethod
    def from_pb(cls, mode: int) -> "TrackMode":
        return _MODES.get(mode, cls.UNSPECIFIED)


_MODES: Dict[int, TrackMode] = {
    pb.TrackedObject.ESTIMATED: TrackMode.ESTIMATED,
    pb.TrackedObject.TRACKED: TrackMode.TRACKED,
    pb.TrackedObject.REINITIALISED: TrackMode.REINITIALISED,
    pb.TrackedObject.LOST: TrackMode.LOST,
    pb.TrackedObject.DROPPED: TrackMode.DROPPED,
    pb.TrackedObject.REFUSED: TrackMode.REFUSED,
}


@dataclass(frozen=True)
class DepthFit:
    """How a pose's model surface lies on the measured depth (RGB-D): shares of the
    measured points within ``tolerance_mm`` of it (``inlier_share``), measured behind it (the
    camera sees through the pose: ``free_space_share``) and in front (occluders:
    ``occluded_share``); the inliers' RMS point-to-plane residual (``rms_mm``, NaN without
    inliers) and how far the fit moved the object (``moved_mm``)."""

    points: int
    measured_share: float
    inlier_share: float
    free_space_share: float
    occluded_share: float
    rms_mm: float
    tolerance_mm: float
    moved_mm: float

    @classmethod
    def from_pb(cls, m: pb.DepthFit) -> "DepthFit":
        return cls(m.points, m.measured_share, m.inlier_share, m.free_space_share, m.occluded_share, m.rms_mm, m.tolerance_mm, m.moved_mm)


@dataclass(frozen=True)
class TrackedObject:
    """One tracked object in one frame, or a detection that started no track (``mode``
    REFUSED, ``track_id`` None). ``pose`` is None when lost, dropped or refused; then
    ``reason`` says why."""

    track_id: Optional[int]
    """The track's number in this stream (None for a refused detection)."""
    object_id: str
    pose: Optional[Pose]
    quality: float
    """Outline agreement in [0, 1] (1 for a pose fresh from a full estimate)."""
    mode: TrackMode
    detection_index: Optional[int]
    """Index into this frame's detections of the one used."""
    ms: float
    """Time the server spent on this object in this frame, milliseconds."""
    reason: Optional[str]
    depth_fit: Optional[DepthFit] = None
    """How the pose lies on the frame's measured surface, on frames tracked with depth."""
    timings_ms: Dict[str, float] = field(default_factory=dict)
    """The tracking step's stage times, milliseconds (colours, contour, photometric, depth,
    relearn, total), on frames the track was followed from the last one; empty for a new
    track or a refused detection."""

    @property
    def ok(self) -> bool:
        return self.pose is not None

    @classmethod
    def from_pb(cls, m: pb.TrackedObject) -> "TrackedObject":
        return cls(
            track_id=m.track_id if m.HasField("track_id") else None,
            object_id=m.object_id,
            pose=pose_from_pb(m.pose) if m.HasField("pose") else None,
            quality=m.quality,
            mode=TrackMode.from_pb(m.mode),
            detection_index=m.detection_index if m.detection_index >= 0 else None,
            ms=m.ms,
            reason=m.reason or None,
            depth_fit=DepthFit.from_pb(m.depth_fit) if m.HasField("depth_fit") else None,
            timings_ms=dict(m.timings_ms),
        )


@dataclass(frozen=True)
class TrackResult:
    """The answer to one frame of a tracking stream: ``objects``, one per tracked object
    (and one per detection that started no track), ``total_ms`` (the frame on the server)
    and ``session_id`` (the stream's session, as GET /v1/tracks lists it).

    A frame the server refused (malformed, out of order, unknown object) has ``error`` set,
    the exception it would raise (:class:`~b2tfpose.InvalidArgument`,
    :class:`~b2tfpose.NotFound`, ...), no objects, and ``frame_index`` None unless the frame
    gave one; the session is as it was before it. ``frame`` is the frame this answers, as
    sent (its image included)."""

    frame_index: Optional[int]
    """The frame's number in the stream (from 0, or as the frames gave them)."""
    objects: List[TrackedObject]
    total_ms: float
    session_id: str
    error: Optional[RpcError] = None
    frame: Optional["TrackFrame"] = field(default=None, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        """The frame was not refused (its objects may still be lost)."""
        return self.error is None

    def best(self, object_id: Optional[str] = None) -> Optional[TrackedObject]:
        """The object with a pose of highest quality (of ``object_id`` if given)."""
        found = [o for o in self.objects if o.pose is not None and (object_id is None or o.object_id == object_id)]
        return max(found, key=lambda o: o.quality) if found else None

    @classmethod
    def from_pb(cls, m: pb.TrackFrameResult, frame: Optional["TrackFrame"] = None) -> "TrackResult":
        if m.HasField("error"):
            code = getattr(grpc.StatusCode, m.error.code, grpc.StatusCode.UNKNOWN)
            if not isinstance(code, grpc.StatusCode):
                code = grpc.StatusCode.UNKNOWN
            index = frame.frame_index if frame is not None and frame.frame_index is not None else None
            error = error_class(code)(code, m.error.message, "Track")
            return cls(frame_index=None if index is None else int(index), objects=[], total_ms=m.total_ms, session_id=m.session_id, error=error, frame=frame)
        return cls(
            frame_index=m.frame_index,
            objects=[TrackedObject.from_pb(o) for o in m.objects],
            total_ms=m.total_ms,
            session_id=m.session_id,
            frame=frame,
        )
