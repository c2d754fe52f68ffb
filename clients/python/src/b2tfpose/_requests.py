"""Request messages from the clients' arguments, and the end of an onboarding, shared by
:class:`b2tfpose.Client` and :class:`b2tfpose.AsyncClient` so both send and accept exactly
the same."""

from __future__ import annotations

from typing import Any, Callable, Dict, List, Literal, Mapping, Optional, Sequence, Union

from ._convert import DepthInput, DetectionInput, ImageInput, IntrinsicsInput, TrackFrame, depth_message, detection_message, image_message, intrinsics_message
from ._mesh import MeshInput, mesh_message
from ._types import CANCELLED, SUCCEEDED, ObjectInfo, OperationStatus
from .errors import OperationCancelled, OperationFailed
from .v1 import pose_service_pb2 as pb

ProgressCallback = Callable[[OperationStatus], None]
PcaSetting = Union[None, int, Literal["auto", "off"]]

REFINERS = ("none", "silhouette-depth", "contour")
DESCRIPTOR_CODINGS = ("f16", "i8", "pq2", "pq4")
PATCH_ROWS = ("per-template", "per-view", "auto")


def pca_fields(pca: PcaSetting) -> Dict[str, Any]:
    """The proto's two PCA fields for ``pca``: None / "auto" (the server's default: only
    descriptors wider than 256 values are compressed), "off" (every dimension kept) or a
    number of components."""
    if pca is None or pca == "auto":
        return {"pca": 0}
    if pca == "off":
        return {"full_descriptors": True}
    if isinstance(pca, bool) or not isinstance(pca, int) or pca < 1:
        raise ValueError(f"pca must be 'auto', 'off' or a number of components >= 1, not {pca!r}")
    return {"pca": pca}


def onboard_request(
    object_id: str,
    mesh: MeshInput,
    *,
    units: Optional[str],
    level: Optional[int],
    in_plane: Optional[int],
    pca: PcaSetting,
    descriptors: Optional[str] = None,
    patch_rows: Optional[str] = None,
    replace: bool,
    format: Optional[str],
    resources: Optional[Mapping[str, bytes]],
) -> pb.OnboardRequest:
    if descriptors is not None and descriptors not in DESCRIPTOR_CODINGS:
        raise ValueError(f"descriptors must be one of {', '.join(DESCRIPTOR_CODINGS)} (None: the server's default), not {descriptors!r}")
    if patch_rows is not None and patch_rows not in PATCH_ROWS:
        raise ValueError(f"patch_rows must be one of {', '.join(PATCH_ROWS)} (None: the server's default), not {patch_rows!r}")
    options = pb.OnboardOptions(in_plane=in_plane or 0, descriptors=descriptors or "", patch_rows=patch_rows or "", **pca_fields(pca))
    if level is not None:
        options.level = level  # optional field: 0 is a real level, unset is the default
    return pb.OnboardRequest(object_id=object_id, mesh=mesh_message(mesh, units, format, resources), options=options, replace=replace)


def objects_list(objects: Optional[Sequence[str]]) -> List[str]:
    if objects is None:
        return []
    if isinstance(objects, (str, bytes)) or not isinstance(objects, Sequence) or not all(isinstance(o, str) for o in objects):
        raise TypeError("objects: a list of object ids (str)")
    return list(objects)


def detect_options(
    max_detections: Optional[int] = None,
    min_score: Optional[float] = None,
    min_distance: Optional[float] = None,
    max_distance: Optional[float] = None,
    refine_masks: Optional[bool] = None,
) -> pb.DetectOptions:
    """The detector's settings; None leaves the server's default (20 detections, score
    0.75, the distances the object's size and the image imply, masks refined)."""
    if max_detections is not None and (isinstance(max_detections, bool) or not isinstance(max_detections, int) or max_detections < 1):
        raise ValueError(f"max_detections must be an integer >= 1 (None: the server's default), not {max_detections!r}")
    if min_score is not None and (isinstance(min_score, bool) or not isinstance(min_score, (int, float)) or not 0.0 <= min_score <= 1.0):
        raise ValueError(f"min_score must be in [0, 1] (None: the server's default), not {min_score!r}")
    options = pb.DetectOptions(max_detections=max_detections or 0)
    if min_score is not None:
        options.min_score = float(min_score)
    for name, v in (("min_distance_m", min_distance), ("max_distance_m", max_distance)):
        if v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ValueError(f"{name.removesuffix('_m')} must be a distance in metres > 0 (None: the server's default), not {v!r}")
            setattr(options, name, float(v))
    if refine_masks is not None:
        options.refine_masks = refine_masks
    return options


def detect_request(
    image: ImageInput,
    K: IntrinsicsInput,
    objects: Optional[Sequence[str]],
    *,
    bgr: bool,
    options: pb.DetectOptions,
    depth: Optional[DepthInput] = None,
    depth_scale: Optional[float] = None,
) -> pb.DetectRequest:
    img, w, h = image_message(image, bgr=bgr)
    if depth is None and depth_scale is not None:
        raise ValueError("depth_scale without depth")
    depth_m = depth_message(depth, depth_scale, w, h) if depth is not None else None
    return pb.DetectRequest(image=img, intrinsics=intrinsics_message(K, w, h), objects=objects_list(objects), options=options, depth=depth_m)


def estimate_request(
    image: ImageInput,
    K: IntrinsicsInput,
    detections: Optional[Sequence[DetectionInput]],
    *,
    objects: Optional[Sequence[str]] = None,
    detect: Optional[pb.DetectOptions] = None,
    bgr: bool,
    rrc: Optional[bool],
    refiner: Optional[str],
    k: Optional[int],
    max_masks: Optional[int],
    instances_per_object: Optional[int],
    verify: Optional[bool],
    verify_templates: Optional[int] = None,
    spin_steps: Optional[int] = None,
    verify_matched: Optional[int] = None,
    nudge_degrees: Optional[float] = None,
    depth_views: Optional[int] = None,
    box_prior: Optional[bool] = None,
    overlay: bool = False,
    depth: Optional[DepthInput] = None,
    depth_scale: Optional[float] = None,
    rrc_always: bool = False,
) -> pb.EstimateRequest:
    ids = objects_list(objects)
    if detections is None:
        detections = []
    if isinstance(detections, Mapping) or not isinstance(detections, Sequence) or isinstance(detections, (str, bytes)):
        raise TypeError("detections: a list of b2tfpose.Detection (or dicts)")
    if detections and ids:
        raise ValueError("give detections or objects, not both")
    if not detections and not ids:
        raise ValueError("detections: at least one is needed (or name objects to detect)")
    if refiner is not None and refiner not in REFINERS:
        raise ValueError(f"refiner {refiner!r}: expected one of {', '.join(REFINERS)}")
    img, w, h = image_message(image, bgr=bgr)
    options = pb.EstimateOptions(k=k or 0, max_masks=max_masks or 0, instances_per_object=instances_per_object or 0, refiner=refiner or "", overlay=bool(overlay), rrc_always=bool(rrc_always))
    if rrc is not None:
        options.rrc = rrc
    if verify is not None:
        options.verify = verify
    if verify_templates is not None:
        options.verify_templates = verify_templates
    if spin_steps is not None:
        options.spin_steps = spin_steps
    if verify_matched is not None:
        options.verify_matched = verify_matched
    if nudge_degrees is not None:
        options.nudge_degrees = nudge_degrees
    if depth_views is not None:
        options.depth_views = depth_views
    if box_prior is not None:
        options.box_prior = box_prior
    if depth is None and depth_scale is not None:
        raise ValueError("depth_scale without depth")
    return pb.EstimateRequest(
        image=img,
        intrinsics=intrinsics_message(K, w, h),
        detections=[detection_message(d, w, h) for d in detections],
        options=options,
        objects=ids,
        detect=detect if detect is not None else pb.DetectOptions(),
        depth=depth_message(depth, depth_scale, w, h) if depth is not None else None,
    )


def track_options(max_tracks: Optional[int], drop_after_lost: Optional[int], lost_below: Optional[float]) -> pb.TrackOptions:
    """The session's options (sent with the first frame); None leaves the server's default
    (8 tracks, dropped after 30 lost frames, lost below 0.3)."""
    for name, n in (("max_tracks", max_tracks), ("drop_after_lost", drop_after_lost)):
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
            raise ValueError(f"{name} must be an integer >= 1 (None: the server's default), not {n!r}")
    options = pb.TrackOptions(max_tracks=max_tracks or 0, drop_after_lost=drop_after_lost or 0)
    if lost_below is not None:
        if isinstance(lost_below, bool) or not isinstance(lost_below, (int, float)) or not 0.0 <= lost_below <= 1.0:
            raise ValueError(f"lost_below must be in [0, 1] (None: the server's default), not {lost_below!r}")
        options.lost_below = float(lost_below)
    return options


def track_frame_message(frame: TrackFrame, *, bgr: bool, options: Optional[pb.TrackOptions]) -> pb.TrackFrame:
    """One frame of the Track stream (``frame.K`` set, see :func:`as_track_frame`);
    ``options`` go with the stream's first frame only."""
    assert frame.K is not None
    img, w, h = image_message(frame.image, bgr=bgr)
    m = pb.TrackFrame(image=img, intrinsics=intrinsics_message(frame.K, w, h), detections=[detection_message(d, w, h) for d in frame.detections], objects=list(frame.objects))
    if frame.frame_index is not None:
        m.frame_index = int(frame.frame_index)
    if frame.depth is not None:
        m.depth.CopyFrom(depth_message(frame.depth, frame.depth_scale, w, h))
    elif frame.depth_scale is not None:
        raise ValueError("depth_scale without depth")
    if options is not None:
        m.options.CopyFrom(options)
    return m


class ProgressFilter:
    """Calls ``progress`` once per distinct state of a watched operation (a stream may
    repeat a state, e.g. after a reconnect)."""

    def __init__(self, progress: Optional[ProgressCallback]) -> None:
        self._progress = progress
        self._last: Optional[OperationStatus] = None

    def __call__(self, status: OperationStatus) -> None:
        if self._progress is not None and status != self._last:
            self._progress(status)
        self._last = status


def finish(status: OperationStatus) -> ObjectInfo:
    """The object of a finished operation, or its failure as an exception."""
    if status.state == SUCCEEDED and status.object is not None:
        return status.object
    if status.state == CANCELLED:
        raise OperationCancelled(status)
    raise OperationFailed(status)
