"""The blocking client, :class:`Client`, and its onboarding handle, :class:`Operation`."""

from __future__ import annotations

import queue
import time
from typing import Any, Callable, Generator, Iterable, Iterator, List, Literal, Mapping, Optional, Sequence, Tuple, TypeVar, Union, overload

import grpc

from . import _requests
from ._channel import HEALTH_CHECK, SERVICE, CaCert, Settings, decode_health_response, encode_health_request, identity
from ._convert import DepthInput, DetectionInput, FrameInput, ImageInput, IntrinsicsInput
from ._mesh import MeshInput
from ._requests import PcaSetting, ProgressCallback, ProgressFilter, finish, track_options
from ._retry import Attempts, RetryArg, RetryPolicy, resolve
from ._track import METHOD as TRACK, TrackState
from ._types import Detections, Estimates, ObjectInfo, OperationStatus, TrackResult
from .errors import DeadlineExceeded, from_grpc
from .v1 import pose_service_pb2 as pb
from .v1 import pose_service_pb2_grpc as pb_grpc

Resp = TypeVar("Resp")


class Operation:
    """A running onboarding: ``status()``, ``wait()`` for its object, ``cancel()``."""

    def __init__(self, client: "Client", status: OperationStatus) -> None:
        self._client = client
        self.id = status.id
        self.object_id = status.object_id
        self.last_status = status

    def status(self) -> OperationStatus:
        """Its current state (GetOperation)."""
        self.last_status = self._client.get_operation(self.id)
        return self.last_status

    def wait(self, progress: Optional[ProgressCallback] = None, timeout: Optional[float] = None) -> ObjectInfo:
        """Follows the operation (WatchOperation) to its end and returns the object;
        raises :class:`~b2tfpose.OperationFailed` / ``OperationCancelled`` otherwise.
        ``progress`` gets every new state."""
        report = ProgressFilter(progress)
        for status in self._client.watch_operation(self.id, timeout=timeout):
            self.last_status = status
            report(status)
        if not self.last_status.done:  # the stream ended early: ask once more
            self.status()
        return finish(self.last_status)

    def cancel(self) -> OperationStatus:
        """Asks the server to stop it; nothing of it is stored. Returns its state (it turns
        CANCELLED shortly after)."""
        self.last_status = self._client.cancel_operation(self.id)
        return self.last_status

    def __repr__(self) -> str:
        return f"Operation(id={self.id!r}, object_id={self.object_id!r}, state={self.last_status.state})"


class _Outbox:
    """The request iterator of a Track stream: grpc's sending thread takes from it what the
    caller's thread puts, so frames are taken from the caller's iterable in the caller's
    thread (its exceptions are the caller's), as the answers come back."""

    def __init__(self) -> None:
        self._queue: "queue.Queue[Optional[pb.TrackFrame]]" = queue.Queue()
        self._closed = False

    def put(self, m: pb.TrackFrame) -> None:
        self._queue.put(m)

    def close(self) -> None:
        """No more frames: the stream is half-closed once the ones put are sent."""
        if not self._closed:
            self._closed = True
            self._queue.put(None)

    def __iter__(self) -> "_Outbox":
        return self

    def __next__(self) -> pb.TrackFrame:
        m = self._queue.get()
        if m is None:
            raise StopIteration
        return m


class Client:
    """A blocking client of a b2tfpose server.

    >>> with b2tfpose.Client("localhost:50051") as c:
    ...     results = c.estimate(rgb, K, objects=["bbq"])  # the server finds it
    ...     results = c.estimate(rgb, K, [b2tfpose.Detection("bbq", mask=mask)])

    ``address``: ``host:port``, ``grpc://host:port`` or ``grpcs://host:port`` (TLS).
    ``api_key``: sent as ``authorization: Bearer KEY``. ``tls`` / ``ca_cert`` (PEM bytes or
    a path: the certificate to trust) / ``server_name`` (the name to verify, when it is not
    the host of ``address``). ``timeout``: default deadline of each call, seconds (None:
    none), retries included. ``retry``: the policy for RESOURCE_EXHAUSTED / UNAVAILABLE;
    idempotent calls use it by default, onboard / delete / cancel only with ``retry=`` per
    call.
    """

    def __init__(
        self,
        address: str,
        api_key: Optional[str] = None,
        *,
        tls: Optional[bool] = None,
        ca_cert: Optional[CaCert] = None,
        server_name: Optional[str] = None,
        timeout: Optional[float] = 60.0,
        retry: Optional[RetryPolicy] = None,
        options: Optional[Sequence[Tuple[str, Union[str, int]]]] = None,
    ) -> None:
        self._settings = Settings.make(address, api_key, tls, ca_cert, server_name, timeout, retry, options)
        self._channel = self._settings.open_sync()
        self._stub = pb_grpc.PoseServiceStub(self._channel)

    # ------------------------------------------------------------------ plumbing

    def _call(self, method: str, fn: Callable[..., Resp], request: Any, timeout: Optional[float], retry: RetryArg, idempotent: bool) -> Resp:
        policy = resolve(retry, self._settings.retry, idempotent)
        attempts = Attempts(method, policy, self._settings.timeout if timeout is None else timeout)
        while True:
            try:
                return fn(request, timeout=attempts.timeout(), metadata=self._settings.call_metadata())
            except grpc.RpcError as e:
                time.sleep(attempts.after_failure(e))

    # ------------------------------------------------------------------ onboarding

    @overload
    def onboard(
        self,
        object_id: str,
        mesh: MeshInput,
        *,
        units: Optional[str] = ...,
        level: Optional[int] = ...,
        in_plane: Optional[int] = ...,
        pca: PcaSetting = ...,
        descriptors: Optional[str] = ...,
        patch_rows: Optional[str] = ...,
        replace: bool = ...,
        format: Optional[str] = ...,
        resources: Optional[Mapping[str, bytes]] = ...,
        progress: Optional[ProgressCallback] = ...,
        wait: Literal[True] = ...,
        timeout: Optional[float] = ...,
        retry: RetryArg = ...,
    ) -> ObjectInfo: ...

    @overload
    def onboard(
        self,
        object_id: str,
        mesh: MeshInput,
        *,
        units: Optional[str] = ...,
        level: Optional[int] = ...,
        in_plane: Optional[int] = ...,
        pca: PcaSetting = ...,
        descriptors: Optional[str] = ...,
        patch_rows: Optional[str] = ...,
        replace: bool = ...,
        format: Optional[str] = ...,
        resources: Optional[Mapping[str, bytes]] = ...,
        progress: Optional[ProgressCallback] = ...,
        wait: Literal[False],
        timeout: Optional[float] = ...,
        retry: RetryArg = ...,
    ) -> Operation: ...

    def onboard(
        self,
        object_id: str,
        mesh: MeshInput,
        *,
        units: Optional[str] = None,
        level: Optional[int] = None,
        in_plane: Optional[int] = None,
        pca: PcaSetting = None,
        descriptors: Optional[str] = None,
        patch_rows: Optional[str] = None,
        replace: bool = False,
        format: Optional[str] = None,
        resources: Optional[Mapping[str, bytes]] = None,
        progress: Optional[ProgressCallback] = None,
        wait: bool = True,
        timeout: Optional[float] = None,
        retry: RetryArg = None,
    ) -> Union[ObjectInfo, Operation]:
        """Onboards a mesh as ``object_id``.

        ``mesh``: a path (PLY / OBJ with its MTL and textures beside it / glTF / GLB),
        bytes (with ``format`` and ``resources`` {name: bytes}), or a trimesh object.
        ``units``: the mesh's length unit, "mm", "cm" or "m" (required but for glTF).
        ``level``: template viewpoints, 0-3 (12, 42, 162, 642; server default 2);
        ``in_plane``: rotations per viewpoint; ``pca``: PCA of the patch descriptors, "auto" (None: the server's default,
        compressing only descriptors wider than 256 values), "off" or a component count;
        ``descriptors``: how they are stored, "f16" (None: the server's default, exact),
        "i8", "pq2" or "pq4" (an eighth of the bytes, some accuracy lost); ``patch_rows``:
        "auto" (None: the server's default; per view with the embedded backbone, per
        template with an ONNX one), "per-view" (a view's in-plane turns share its rows,
        about a twelfth of the bytes; estimates encode the query per turn) or "per-template".
        Waits for the object (``progress`` gets each state; ``timeout`` bounds the wait,
        None: no limit), or with ``wait=False`` returns the :class:`Operation` at once.
        """
        request = _requests.onboard_request(
            object_id, mesh, units=units, level=level, in_plane=in_plane, pca=pca, descriptors=descriptors, patch_rows=patch_rows, replace=replace, format=format, resources=resources
        )
        status = OperationStatus.from_pb(self._call("Onboard", self._stub.Onboard, request, None, retry, idempotent=False))
        op = Operation(self, status)
        if not wait:
            return op
        return op.wait(progress=progress, timeout=timeout)

    def get_operation(self, operation_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> OperationStatus:
        m = self._call("GetOperation", self._stub.GetOperation, pb.GetOperationRequest(id=operation_id), timeout, retry, idempotent=True)
        return OperationStatus.from_pb(m)

    def operation(self, operation_id: str) -> Operation:
        """A handle on an operation by id (e.g. one started by another process)."""
        return Operation(self, self.get_operation(operation_id))

    def watch_operation(self, operation_id: str, *, timeout: Optional[float] = None) -> Iterator[OperationStatus]:
        """Each state of the operation until its final one (WatchOperation). ``timeout``
        bounds the whole watch (None: no limit)."""
        stream = self._stub.WatchOperation(pb.GetOperationRequest(id=operation_id), timeout=timeout, metadata=self._settings.call_metadata())
        try:
            for m in stream:
                yield OperationStatus.from_pb(m)
        except grpc.RpcError as e:
            raise from_grpc(e, "WatchOperation") from None
        finally:
            stream.cancel()

    def cancel_operation(self, operation_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> OperationStatus:
        m = self._call("CancelOperation", self._stub.CancelOperation, pb.GetOperationRequest(id=operation_id), timeout, retry, idempotent=False)
        return OperationStatus.from_pb(m)

    # ------------------------------------------------------------------ estimation

    def estimate(
        self,
        image: ImageInput,
        K: IntrinsicsInput,
        detections: Optional[Sequence[DetectionInput]] = None,
        *,
        objects: Optional[Sequence[str]] = None,
        bgr: bool = False,
        rrc: Optional[bool] = None,
        rrc_always: bool = False,
        refiner: Optional[str] = None,
        k: Optional[int] = None,
        max_masks: Optional[int] = None,
        instances_per_object: Optional[int] = None,
        verify: Optional[bool] = None,
        verify_templates: Optional[int] = None,
        spin_steps: Optional[int] = None,
        verify_matched: Optional[int] = None,
        nudge_degrees: Optional[float] = None,
        depth_views: Optional[int] = None,
        box_prior: Optional[bool] = None,
        overlay: bool = False,
        depth: Optional[DepthInput] = None,
        depth_scale: Optional[float] = None,
        max_detections: Optional[int] = None,
        min_score: Optional[float] = None,
        min_distance: Optional[float] = None,
        max_distance: Optional[float] = None,
        timeout: Optional[float] = None,
        retry: RetryArg = None,
    ) -> Estimates:
        """Estimates the pose of each object instance in ``image``.

        ``image``: numpy HxWx3 uint8 RGB (``bgr=True`` for OpenCV frames), PNG/JPEG bytes,
        or a path. ``K``: 3x3 or (fx, fy, cx, cy), pixels. ``detections``:
        :class:`~b2tfpose.Detection` objects or dicts with the same keys; or, instead,
        ``objects``: ids the server detects first (as :meth:`detect`, with its
        ``max_detections``, ``min_score``, ``min_distance``, ``max_distance``), then
        estimates (``.detections`` of the result lists what it found). ``rrc``,
        ``rrc_always`` (RRC also where the first matches are sure enough to skip it),
        ``refiner`` ("contour", "silhouette-depth", "none"), ``k``, ``max_masks``,
        ``instances_per_object``, ``verify``, ``verify_templates``, ``spin_steps``, ``verify_matched``,
        ``nudge_degrees`` (0: off), ``depth_views`` (with depth: template views found
        on the measured surface, judged and reviewed against; 0: off), ``box_prior`` (True: boxes drawn tight, always held; False: drawn loose, never; None: the server's default, held for meshes without colours): the server's options
        (None: its default). ``overlay=True``: the answer's
        ``.overlay_png`` is the photo with the poses drawn on it (PNG bytes).
        ``depth``: an RGB-D camera's depth registered to ``image`` (same size and K):
        numpy HxW uint16 with ``depth_scale`` millimetres per unit (1 for millimetres, 0.1
        for tenths), float metres, or a 16-bit PNG's bytes or path with ``depth_scale``; 0 =
        no measurement. Each hypothesis is then fitted to the measured surface and judged
        on it (``diagnostics[i]["refinement"]["depth_fit"]``).
        Returns a list of :class:`~b2tfpose.Result` (``.total_ms``: the server's time).
        """
        request = _requests.estimate_request(
            image,
            K,
            detections,
            objects=objects,
            detect=_requests.detect_options(max_detections, min_score, min_distance, max_distance),
            bgr=bgr,
            rrc=rrc,
            rrc_always=rrc_always,
            refiner=refiner,
            k=k,
            max_masks=max_masks,
            instances_per_object=instances_per_object,
            verify=verify,
            verify_templates=verify_templates,
            spin_steps=spin_steps,
            verify_matched=verify_matched,
            nudge_degrees=nudge_degrees,
            depth_views=depth_views,
            box_prior=box_prior,
            overlay=overlay,
            depth=depth,
            depth_scale=depth_scale,
        )
        return Estimates.from_pb(self._call("Estimate", self._stub.Estimate, request, timeout, retry, idempotent=True))

    def detect(
        self,
        image: ImageInput,
        K: IntrinsicsInput,
        objects: Optional[Sequence[str]] = None,
        *,
        bgr: bool = False,
        max_detections: Optional[int] = None,
        min_score: Optional[float] = None,
        min_distance: Optional[float] = None,
        max_distance: Optional[float] = None,
        refine_masks: Optional[bool] = None,
        depth: Optional[DepthInput] = None,
        depth_scale: Optional[float] = None,
        timeout: Optional[float] = None,
        retry: RetryArg = None,
    ) -> Detections:
        """Finds objects in ``image`` with no mask and no box: the server's training-free
        detector (shape-based matching of templates rendered from each mesh).

        ``objects``: the ids to look for (None or empty: every object in the store, at most
        64). ``max_detections`` (1-256), ``min_score`` (0-1), ``min_distance`` /
        ``max_distance`` (metres from the camera to search), ``refine_masks``: the
        detector's settings (None: the server's defaults, 20, 0.75, from the object's size
        and the image, on). Returns :class:`~b2tfpose.Detections`, best first; each is a
        :class:`~b2tfpose.Detection` that :meth:`estimate` takes as it is. Finding nothing
        is an empty list with ``.reason``, not an error. ``depth`` / ``depth_scale``: an
        RGB-D camera's depth registered to ``image``, as :meth:`estimate` takes it; the
        objects are then looked for among the surfaces standing off the table, of their size
        (each detection's ``mask_source`` is ``"depth_segment"``).
        """
        options = _requests.detect_options(max_detections, min_score, min_distance, max_distance, refine_masks)
        request = _requests.detect_request(image, K, objects, bgr=bgr, options=options, depth=depth, depth_scale=depth_scale)
        return Detections.from_pb(self._call("Detect", self._stub.Detect, request, timeout, retry, idempotent=True))

    # ------------------------------------------------------------------ tracking

    def track(
        self,
        frames: Iterable[FrameInput],
        *,
        K: Optional[IntrinsicsInput] = None,
        bgr: bool = False,
        max_tracks: Optional[int] = None,
        drop_after_lost: Optional[int] = None,
        lost_below: Optional[float] = None,
        objects: Optional[Sequence[str]] = None,
        min_score: Optional[float] = None,
        max_detections: Optional[int] = None,
        raise_errors: bool = True,
        prefetch: int = 1,
        timeout: Optional[float] = None,
        retry: RetryArg = None,
    ) -> Generator[TrackResult, None, None]:
        """Tracks objects through a video: one :class:`~b2tfpose.TrackResult` per frame, in
        order, as the server answers (the Track stream: one tracking session).

        ``frames``: any iterable (a list, a generator reading a camera), taken lazily; each a
        :class:`~b2tfpose.TrackFrame`, a dict with its keys, an ``(image, K)`` or ``(image, K,
        detections)`` tuple, or a bare image. ``K``: the intrinsics of frames that give none.
        ``bgr``: numpy frames are OpenCV's BGR. A detection that no track of its object
        overlaps starts a track (a full estimate, mode ESTIMATED); later frames need none
        (TRACKED); a lost track is re-initialised from a detection over it or by searching
        near its last pose. ``max_tracks`` (1-32), ``drop_after_lost`` (lost frames before a
        track ends), ``lost_below`` (outline agreement, 0-1, under which a frame is lost): the
        session's options (None: the server's defaults, 8, 30, 0.3). ``objects``: ids the
        server's detector looks for in each frame that gives no detections or objects of its
        own, each only while no track of it was followed into the last frame: the first
        frame needs no mask, and a lost object is found again (``min_score``,
        ``max_detections``: the detector's settings, as :meth:`detect`'s).

        A frame the server refuses (malformed, out of order, unknown object) raises its
        error (InvalidArgument, NotFound, ...), which ends the stream; with
        ``raise_errors=False`` it is returned as the frame's ``result.error`` instead and the
        stream goes on, the session as it was. Frames that cannot be sent at all raise
        ValueError / TypeError. A status ending the stream raises its class:
        ResourceExhausted (the server's sessions are all open), DeadlineExceeded (no frame
        for the server's idle timeout, or past ``timeout``), Unavailable...

        ``prefetch``: frames taken and sent ahead of the answers once the first frame was
        answered, 0-3 (1: the next frame travels while the server works on this one; 0: each
        frame is taken once the last one's result was handled, for frames that depend on it). ``timeout`` bounds the whole
        stream (None: no limit). Only the opening is retried (``retry``: the client's policy
        by default), re-sending the first frame: once a frame was answered the session has
        state a new stream would not. Leaving the loop early ends the stream (``close()``
        ends it at once; a ``break`` does once nothing refers to the iterator).
        """
        state = TrackState(
            track_options(max_tracks, drop_after_lost, lost_below),
            K,
            bgr,
            raise_errors,
            prefetch,
            Attempts(TRACK, resolve(retry, self._settings.retry, idempotent=True), timeout),
            _requests.objects_list(objects),
            _requests.detect_options(max_detections, min_score),
        )
        return self._track(iter(frames), state)

    def _track(self, source: Iterator[FrameInput], state: TrackState) -> Generator[TrackResult, None, None]:
        while True:  # one stream per attempt
            outbox = _Outbox()
            answers = self._stub.Track(outbox, timeout=state.attempts.timeout(), metadata=self._settings.call_metadata())
            try:
                for m in state.replay():
                    outbox.put(m)
                while True:
                    while state.wants_frame():
                        try:
                            frame = next(source)
                        except StopIteration:
                            state.exhausted = True
                            break
                        outbox.put(state.add(frame))
                    if state.exhausted:
                        outbox.close()
                        if not state.pending:
                            for _ in answers:  # the stream's end (and its status)
                                pass
                            return
                    answer = next(answers, None)
                    if answer is None:
                        raise state.ended_early()
                    yield state.answer(answer)
            except grpc.RpcError as e:
                delay = state.failure(e)  # raises unless the opening is retried
            finally:
                outbox.close()
                answers.cancel()
            time.sleep(delay)

    # ------------------------------------------------------------------ objects

    def list_objects(self, *, timeout: Optional[float] = None, retry: RetryArg = None) -> List[ObjectInfo]:
        m = self._call("ListObjects", self._stub.ListObjects, pb.ListObjectsRequest(), timeout, retry, idempotent=True)
        return [ObjectInfo.from_pb(o) for o in m.objects]

    def get_object(self, object_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> ObjectInfo:
        m = self._call("GetObject", self._stub.GetObject, pb.GetObjectRequest(object_id=object_id), timeout, retry, idempotent=True)
        return ObjectInfo.from_pb(m)

    def delete_object(self, object_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> None:
        self._call("DeleteObject", self._stub.DeleteObject, pb.GetObjectRequest(object_id=object_id), timeout, retry, idempotent=False)

    # ------------------------------------------------------------------ health

    def health(self, service: str = SERVICE, *, timeout: Optional[float] = None, retry: RetryArg = None) -> str:
        """The standard health check: "SERVING" once the server is warmed up, else
        "NOT_SERVING" (or "SERVICE_UNKNOWN"). Needs no API key."""
        check = self._channel.unary_unary(HEALTH_CHECK, request_serializer=identity, response_deserializer=identity)
        return decode_health_response(self._call("Health/Check", check, encode_health_request(service), timeout, retry, idempotent=True))

    def wait_ready(self, timeout: float = 60.0, interval: float = 0.2) -> None:
        """Blocks until the server answers SERVING; raises DeadlineExceeded after
        ``timeout`` seconds."""
        end = time.monotonic() + timeout
        last = "no answer"
        while time.monotonic() < end:
            try:
                last = self.health(timeout=max(0.1, min(5.0, end - time.monotonic())), retry=False)
                if last == "SERVING":
                    return
            except Exception as e:  # noqa: BLE001 - any failure is "not yet"
                last = str(e)
            time.sleep(interval)
        raise DeadlineExceeded(grpc.StatusCode.DEADLINE_EXCEEDED, f"server at {self._settings.target} not ready within {timeout} s ({last})", "wait_ready")

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Client({self._settings.target!r}, tls={self._settings.credentials is not None})"
