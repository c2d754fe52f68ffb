"""The bookkeeping of one tracking stream (the Track RPC), shared by :meth:`b2tfpose.Client.track`
and :meth:`b2tfpose.AsyncClient.track`, which each drive it with their own I/O: which frames
to take and send, the answers matched to the frames in order, and when a failure may be
retried.

A stream is one tracking session on the server. It is retried only before its first answer
(a refusal at opening: RESOURCE_EXHAUSTED when the server's sessions are all taken, or no
server yet), re-sending its first frame (sent alone, the others wait for its answer); once
a frame was answered the session holds state that a new stream would not have, so a
failure then is raised.
"""

from __future__ import annotations

import collections
from dataclasses import replace
from typing import Deque, List, Optional, Sequence, Tuple

import grpc

from ._convert import FrameInput, IntrinsicsInput, TrackFrame, as_track_frame
from ._requests import track_frame_message
from ._retry import Attempts
from ._types import TrackResult
from .errors import RpcError, from_grpc
from .v1 import pose_service_pb2 as pb

METHOD = "Track"
# Frames sent ahead of the answers at most. The server reads a frame only after queuing the
# last one's answer and queues at most 4 answers, so a client that writes this many before
# reading can never wait on a server waiting on it.
MAX_PREFETCH = 3


class TrackState:
    """One ``track()`` call: its options, the frames sent and not yet answered, and its
    attempts (one per stream opened)."""

    def __init__(
        self,
        options: pb.TrackOptions,
        K: Optional[IntrinsicsInput],
        bgr: bool,
        raise_errors: bool,
        prefetch: int,
        attempts: Attempts,
        objects: Sequence[str] = (),
        detect: Optional[pb.DetectOptions] = None,
    ) -> None:
        if isinstance(prefetch, bool) or not isinstance(prefetch, int) or not 0 <= prefetch <= MAX_PREFETCH:
            raise ValueError(f"prefetch must be an integer from 0 to {MAX_PREFETCH}, not {prefetch!r}")
        self.options = options
        self.objects = list(objects)
        self.detect = detect
        self.K = K
        self.bgr = bgr
        self.raise_errors = raise_errors
        self.prefetch = prefetch
        self.attempts = attempts
        self.pending: Deque[Tuple[TrackFrame, pb.TrackFrame]] = collections.deque()
        self.exhausted = False  # the caller's frames have run out
        self.answered = False  # an answer came: no more retries
        self.sent = 0

    def wants_frame(self) -> bool:
        """Whether to take another frame before waiting for the next answer: one frame in
        flight, plus ``prefetch`` sent ahead once the stream is open (the first frame goes
        alone: a stream refused at opening then has nothing else in flight)."""
        return not self.exhausted and len(self.pending) <= (self.prefetch if self.answered else 0)

    def add(self, f: FrameInput) -> pb.TrackFrame:
        """The message of the next frame (the stream's options go with the first); it waits
        for its answer in ``pending``. Bad inputs raise ValueError / TypeError here."""
        frame = as_track_frame(f, self.K)
        if self.objects and not frame.detections and not frame.objects:
            frame = replace(frame, objects=self.objects)
        m = track_frame_message(frame, bgr=self.bgr, options=self.options if self.sent == 0 else None)
        if frame.objects and self.detect is not None:
            m.detect.CopyFrom(self.detect)
        self.pending.append((frame, m))
        self.sent += 1
        return m

    def replay(self) -> List[pb.TrackFrame]:
        """What a new stream must send first: the frame taken so far (the first, with the
        options: nothing was answered)."""
        return [m for _, m in self.pending]

    def answer(self, m: pb.TrackFrameResult) -> TrackResult:
        """The result of the oldest pending frame; its error raised with ``raise_errors``."""
        if not self.pending:
            raise RpcError(grpc.StatusCode.INTERNAL, "the server answered a frame that was not sent", METHOD)
        frame, _ = self.pending.popleft()
        self.answered = True
        result = TrackResult.from_pb(m, frame)
        if result.error is not None and self.raise_errors:
            raise result.error
        return result

    def ended_early(self) -> RpcError:
        """The server ended the stream early without an error status."""
        unanswered = f" with {len(self.pending)} frame(s) unanswered" if self.pending else ""
        return RpcError(grpc.StatusCode.UNKNOWN, f"the server ended the stream{unanswered}", METHOD)

    def failure(self, err: grpc.RpcError) -> float:
        """The delay before opening the stream again, or raises the mapped error: only a
        stream that was never answered is retried (by the call's policy)."""
        if self.answered:
            raise from_grpc(err, METHOD) from None
        return self.attempts.after_failure(err)
