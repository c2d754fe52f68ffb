"""b2tfpose: Python client of the b2tfpose 6DoF pose-estimation service.

>>> import b2tfpose
>>> with b2tfpose.Client("localhost:50051") as c:
...     c.onboard("box", "box.obj", units="m", level=1)
...     [r] = c.estimate(rgb, K, objects=["box"])  # detected by the server
...     [r] = c.estimate(rgb, K, [b2tfpose.Detection("box", mask=mask)])
...     r.pose.R, r.pose.t, r.pose.rvec
...     for f in c.track(video, K=K):  # the first frame a TrackFrame with a detection
...         f.objects[0].mode, f.objects[0].pose
"""

from ._convert import Detection, TrackFrame
from ._pose import Pose
from ._request_id import request_id
from ._retry import NO_RETRY, RetryPolicy
from ._types import ContinuousSymmetry, DepthFit, DetectedObject, Detections, Estimates, ObjectInfo, OperationStatus, Result, RunnerUp, Symmetries, TrackedObject, TrackMode, TrackResult
from .aio import AsyncClient, AsyncOperation
from .client import Client, Operation
from .errors import (
    AlreadyExists,
    B2TFPoseError,
    DeadlineExceeded,
    Internal,
    InvalidArgument,
    NotFound,
    OperationCancelled,
    OperationFailed,
    PermissionDenied,
    ResourceExhausted,
    RpcError,
    Unauthenticated,
    Unavailable,
)

__version__ = "0.1.0"

__all__ = [
    "Client",
    "AsyncClient",
    "Operation",
    "AsyncOperation",
    "Detection",
    "DetectedObject",
    "Detections",
    "Pose",
    "Result",
    "RunnerUp",
    "Estimates",
    "TrackFrame",
    "TrackResult",
    "TrackedObject",
    "DepthFit",
    "TrackMode",
    "ObjectInfo",
    "Symmetries",
    "ContinuousSymmetry",
    "OperationStatus",
    "RetryPolicy",
    "NO_RETRY",
    "request_id",
    "B2TFPoseError",
    "RpcError",
    "InvalidArgument",
    "NotFound",
    "PermissionDenied",
    "AlreadyExists",
    "Unauthenticated",
    "ResourceExhausted",
    "DeadlineExceeded",
    "Unavailable",
    "Internal",
    "OperationFailed",
    "OperationCancelled",
]
