"""The asyncio client, :class:`AsyncClient` (grpc.aio), with the same methods as
:class:`b2tfpose.Client` as coroutines; requests and responses go through the same
shared builders and parsers."""

from __future__ import annotations

import asyncio
from typing import Any, AsyncGenerator, AsyncIterable, AsyncIterator, Awaitable, Callable, Iterable, Iterator, List, Literal, Mapping, Optional, Sequence, Tuple, TypeVar, Union, overload

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


class AsyncOperation:
    """A running onboarding (asyncio): ``await status()``, ``await wait()``,
    ``await cancel()``."""

    def __init__(self, client: "AsyncClient", status: OperationStatus) -> None:
        self._client = client
        self.id = status.id
        self.object_id = status.object_id
        self.last_status = status

    async def status(self) -> OperationStatus:
        self.last_status = await self._client.get_operation(self.id)
        return self.last_status

    async def wait(self, progress: Optional[ProgressCallback] = None, timeout: Optional[float] = None) -> ObjectInfo:
        """As :meth:`b2tfpose.Operation.wait`."""
        report = ProgressFilter(progress)
        async for status in self._client.watch_operation(self.id, timeout=timeout):
            self.last_status = status
            report(status)
        if not self.last_status.done:
            await self.status()
        return finish(self.last_status)

    async def cancel(self) -> OperationStatus:
        self.last_status = await self._client.cancel_operation(self.id)
        return self.last_status

    def __repr__(self) -> str:
        return f"AsyncOperation(id={self.id!r}, object_id={self.object_id!r}, state={self.last_status.state})"


class _Frames:
    """The caller's frames, an async or a plain iterable, taken one at a time."""

    def __init__(self, frames: Union[AsyncIterable[FrameInput], Iterable[FrameInput]]) -> None:
        self._async: Optional[AsyncIterator[FrameInput]] = None
        self._sync: Optional[Iterator[FrameInput]] = None
        if isinstance(frames, AsyncIterable):
            self._async = frames.__aiter__()
        else:
            self._sync = iter(frames)

    async def next(self) -> FrameInput:
        """The next frame; StopAsyncIteration once they have run out."""
        if self._async is not None:
            return await self._async.__anext__()
        assert self._sync is not None
        try:
            return next(self._sync)
        except StopIteration:
            raise StopAsyncIteration from None


# Event-loop turns given before each write to a Track stream, so that a status the server
# already sent (an idle stream ended while the loop was busy) is taken in first: grpc.aio
# replaces the status of a call that ended under a write with INTERNAL "Internal error from
# Core", so the real one (DEADLINE_EXCEEDED...) would be lost. Three turns sufficed in the
# tests (tests/test_track.py blocks the loop past the server's idle timeout).
_SETTLE_TURNS = 5


async def _ended(call: Any) -> bool:
    for _ in range(_SETTLE_TURNS):
        await asyncio.sleep(0)
    return bool(call.done())


async def _send(call: Any, m: pb.TrackFrame) -> bool:
    """Writes a frame; False when the stream has ended (its status comes with the next
    read, where it is raised)."""
    if await _ended(call):
        return False
    try:
        await call.write(m)
        return True
    except (grpc.RpcError, asyncio.InvalidStateError):
        return False


async def _close_sending(call: Any) -> None:
    """Half-closes the stream (no more frames), unless it has ended (its status comes with
    the next read)."""
    if await _ended(call):
        return
    try:
        await call.done_writing()
    except Exception:  # noqa: BLE001 - an ended call (grpc's internal error type): the read raises its status
        pass


class AsyncClient:
    """An asyncio client of a b2tfpose server; arguments as :class:`b2tfpose.Client`.

    >>> async with b2tfpose.AsyncClient("localhost:50051") as c:
    ...     results = await asyncio.gather(*(c.estimate(img, K, dets) for img in images))

    Create it inside the running event loop (grpc.aio binds its channel to it).
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
        self._channel = self._settings.open_aio()
        self._stub = pb_grpc.PoseServiceStub(self._channel)

    async def _call(self, method: str, fn: Callable[..., Awaitable[Resp]], request: Any, timeout: Optional[float], retry: RetryArg, idempotent: bool) -> Resp:
        policy = resolve(retry, self._settings.retry, idempotent)
        attempts = Attempts(method, policy, self._settings.timeout if timeout is None else timeout)
        while True:
            try:
                return await fn(request, timeout=attempts.timeout(), metadata=self._settings.call_metadata())
            except grpc.RpcError as e:
                await asyncio.sleep(attempts.after_failure(e))

    @overload
    async def onboard(
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
    async def onboard(
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
    ) -> AsyncOperation: ...

    async def onboard(
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
    ) -> Union[ObjectInfo, AsyncOperation]:
        """As :meth:`b2tfpose.Client.onboard`."""
        request = _requests.onboard_request(
            object_id, mesh, units=units, level=level, in_plane=in_plane, pca=pca, descriptors=descriptors, patch_rows=patch_rows, replace=replace, format=format, resources=resources
        )
        status = OperationStatus.from_pb(await self._call("Onboard", self._stub.Onboard, request, None, retry, idempotent=False))
        op = AsyncOperation(self, status)
        if not wait:
            return op
        return await op.wait(progress=progress, timeout=timeout)

    async def get_operation(self, operation_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> OperationStatus:
        m = await self._call("GetOperation", self._stub.GetOperation, pb.GetOperationRequest(id=operation_id), timeout, retry, idempotent=True)
        return OperationStatus.from_pb(m)

    async def operation(self, operation_id: str) -> AsyncOperation:
        return AsyncOperation(self, await self.get_operation(operation_id))

    async def watch_operation(self, operation_id: str, *, timeout: Optional[float] = None) -> AsyncIterator[OperationStatus]:
        """As :meth:`b2tfpose.Client.watch_operation`."""
        stream = self._stub.WatchOperation(pb.GetOperationRequest(id=operation_id), timeout=timeout, metadata=self._settings.call_metadata())
        try:
            async for m in stream:
                yield OperationStatus.from_pb(m)
        except grpc.RpcError as e:
            raise from_grpc(e, "WatchOperation") from None
        finally:
            stream.cancel()

    async def cancel_operation(self, operation_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> OperationStatus:
        m = await self._call("CancelOperation", self._stub.CancelOperation, pb.GetOperationRequest(id=operation_id), timeout, retry, idempotent=False)
        return OperationStatus.from_pb(m)

    async def estimate(
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
        """As :meth:`b2tfpose.Client.estimate`."""
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
        return Estimates.from_pb(await self._call("Estimate", self._stub.Estimate, request, timeout, retry, idempotent=True))

    async def detect(
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
        """As :meth:`b2tfpose.Client.detect`."""
        options = _requests.detect_options(max_detections, min_score, min_distance, max_distance, refine_masks)
        request = _requests.detect_request(image, K, objects, bgr=bgr, options=options, depth=depth, depth_scale=depth_scale)
        return Detections.from_pb(await self._call("Detect", self._stub.Detect, request, timeout, retry, idempotent=True))

    def track(
        self,
        frames: Union[AsyncIterable[FrameInput], Iterable[FrameInput]],
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
    ) -> AsyncGenerator[TrackResult, None]:
        """As :meth:`b2tfpose.Client.track`, as an async iterator (``async for result in
        client.track(frames)``); ``frames`` is an async iterable or a plain one. Leaving the
        loop early ends the stream when the iterator is closed (``aclose()``, or when it is
        garbage-collected)."""
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
        return self._track(_Frames(frames), state)

    async def _track(self, source: _Frames, state: TrackState) -> AsyncGenerator[TrackResult, None]:
        while True:  # one stream per attempt
            call = self._stub.Track(timeout=state.attempts.timeout(), metadata=self._settings.call_metadata())
            writable, closed = True, False
            try:
                for m in state.replay():
                    writable = writable and await _send(call, m)
                while True:
                    while writable and state.wants_frame():
                        try:
                            frame = await source.next()
                        except StopAsyncIteration:
                            state.exhausted = True
                            break
                        writable = await _send(call, state.add(frame))
                    if writable and state.exhausted and not closed:
                        await _close_sending(call)
                        closed = True
                    if state.exhausted and not state.pending:
                        while await call.read() is not grpc.aio.EOF:  # the stream's end (and its status)
                            pass
                        return
                    answer = await call.read()  # a stream that ended raises its status here
                    if not isinstance(answer, pb.TrackFrameResult):  # EOF
                        raise state.ended_early()
                    yield state.answer(answer)
            except grpc.RpcError as e:
                delay = state.failure(e)  # raises unless the opening is retried
            finally:
                call.cancel()
            await asyncio.sleep(delay)

    async def list_objects(self, *, timeout: Optional[float] = None, retry: RetryArg = None) -> List[ObjectInfo]:
        m = await self._call("ListObjects", self._stub.ListObjects, pb.ListObjectsRequest(), timeout, retry, idempotent=True)
        return [ObjectInfo.from_pb(o) for o in m.objects]

    async def get_object(self, object_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> ObjectInfo:
        m = await self._call("GetObject", self._stub.GetObject, pb.GetObjectRequest(object_id=object_id), timeout, retry, idempotent=True)
        return ObjectInfo.from_pb(m)

    async def delete_object(self, object_id: str, *, timeout: Optional[float] = None, retry: RetryArg = None) -> None:
        await self._call("DeleteObject", self._stub.DeleteObject, pb.GetObjectRequest(object_id=object_id), timeout, retry, idempotent=False)

    async def health(self, service: str = SERVICE, *, timeout: Optional[float] = None, retry: RetryArg = None) -> str:
        """As :meth:`b2tfpose.Client.health`."""
        check = self._channel.unary_unary(HEALTH_CHECK, request_serializer=identity, response_deserializer=identity)
        return decode_health_response(await self._call("Health/Check", check, encode_health_request(service), timeout, retry, idempotent=True))

    async def wait_ready(self, timeout: float = 60.0, interval: float = 0.2) -> None:
        """As :meth:`b2tfpose.Client.wait_ready`."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        last = "no answer"
        while loop.time() < end:
            try:
                last = await self.health(timeout=max(0.1, min(5.0, end - loop.time())), retry=False)
                if last == "SERVING":
                    return
            except Exception as e:  # noqa: BLE001 - any failure is "not yet"
                last = str(e)
            await asyncio.sleep(interval)
        raise DeadlineExceeded(grpc.StatusCode.DEADLINE_EXCEEDED, f"server at {self._settings.target} not ready within {timeout} s ({last})", "wait_ready")

    async def close(self) -> None:
        await self._channel.close()

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def __repr__(self) -> str:
        return f"AsyncClient({self._settings.target!r}, tls={self._settings.credentials is not None})"
