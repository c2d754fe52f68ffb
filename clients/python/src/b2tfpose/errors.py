"""The exceptions: one class per gRPC status the service answers with, under one base
(any other status, which the service does not send, raises :class:`RpcError` itself).

Every failed call raises a subclass of :class:`RpcError` carrying the status code, the
server's message (which names the offending field for INVALID_ARGUMENT) and the server's
request id (``request_id``: the ``x-request-id`` of the answer, the key to the server's log
lines and trace of the call). A finished
onboarding that failed or was cancelled raises :class:`OperationFailed`.
"""

from __future__ import annotations

from typing import Dict, Optional, Protocol, Type

import grpc


class FinalState(Protocol):
    """What an onboarding's final state tells of it (``OperationStatus`` has it); named
    here so that the errors need nothing of the types that use them."""

    @property
    def id(self) -> str: ...
    @property
    def object_id(self) -> str: ...
    @property
    def state(self) -> str: ...
    @property
    def error(self) -> Optional[str]: ...


class B2TFPoseError(Exception):
    """Base of every error this package raises on purpose (bad inputs raise ValueError /
    TypeError before anything is sent)."""


class RpcError(B2TFPoseError):
    """A gRPC call failed. ``code`` is the status, ``message`` the server's explanation,
    ``request_id`` the server's id of the call (None when no server answered),
    ``retry_after`` the seconds the server asked to wait before retrying (a refusal of
    RESOURCE_EXHAUSTED; None otherwise)."""

    def __init__(self, code: grpc.StatusCode, message: str, method: str = "", request_id: Optional[str] = None, retry_after: Optional[float] = None) -> None:
        self.code = code
        self.message = message
        self.method = method
        self.request_id = request_id
        self.retry_after = retry_after
        where = f"{method}: " if method else ""
        rid = f" (request id {request_id})" if request_id else ""
        super().__init__(f"{where}{code.name}: {message}{rid}")


class InvalidArgument(RpcError):
    """A field of the request is invalid; the message names it."""


class PermissionDenied(RpcError):
    """The server refuses this kind of call: the API key lacks the scope the call needs
    (``read``, ``write`` or ``admin``; the message names it), or onboard and delete on a
    read-only replica (``b2tf serve --read-only``; the message says where to do it
    instead)."""


class NotFound(RpcError):
    """Unknown object or operation."""


class AlreadyExists(RpcError):
    """The object id is taken (onboard without ``replace``) or is being onboarded."""


class Unauthenticated(RpcError):
    """Missing or unknown API key."""


class ResourceExhausted(RpcError):
    """The server's estimate queue is full (``--max-estimates`` running, ``--queue-depth``
    waiting) or its wait would pass the call's deadline, onboardings are running, or the
    API key is over its rate limit (``b2tf serve --rate-limit``): retry after
    ``retry_after`` seconds (the client does so, within its retry budget, unless told
    not to)."""


class DeadlineExceeded(RpcError):
    """The call's deadline (``timeout``) or the server's request limit passed."""


class Unavailable(RpcError):
    """The server cannot be reached (down, wrong address, TLS mismatch) or is shutting
    down."""


class Internal(RpcError):
    """The server failed, e.g. on a damaged object in its store (the message names it)."""


_BY_CODE: Dict[grpc.StatusCode, Type[RpcError]] = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgument,
    # The server rewrites oversized messages to INVALID_ARGUMENT; a client-side limit
    # still says OUT_OF_RANGE.
    grpc.StatusCode.OUT_OF_RANGE: InvalidArgument,
    grpc.StatusCode.NOT_FOUND: NotFound,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDenied,
    grpc.StatusCode.ALREADY_EXISTS: AlreadyExists,
    grpc.StatusCode.UNAUTHENTICATED: Unauthenticated,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhausted,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceeded,
    grpc.StatusCode.UNAVAILABLE: Unavailable,
    grpc.StatusCode.INTERNAL: Internal,
}


def error_class(code: grpc.StatusCode) -> Type[RpcError]:
    """The exception class for a status code (:class:`RpcError` itself for the rest)."""
    return _BY_CODE.get(code, RpcError)


def from_grpc(err: grpc.RpcError, method: str = "") -> RpcError:
    """Turns grpcio's exception (sync or aio) into ours."""
    code_fn = getattr(err, "code", None)
    details_fn = getattr(err, "details", None)
    code = code_fn() if callable(code_fn) else grpc.StatusCode.UNKNOWN
    message = details_fn() if callable(details_fn) else str(err)
    if not isinstance(code, grpc.StatusCode):
        code = grpc.StatusCode.UNKNOWN
    return error_class(code)(code, message or "", method, request_id(err), retry_after(err))


def request_id(call: object) -> Optional[str]:
    """The ``x-request-id`` a server answered with: in the trailers of an error (where a
    trailers-only answer's headers end up too), else in the initial headers."""
    for name in ("trailing_metadata", "initial_metadata"):
        fn = getattr(call, name, None)
        try:
            for key, value in (fn() if callable(fn) else None) or ():
                if key == "x-request-id":
                    return value if isinstance(value, str) else value.decode("ascii", "replace")
        except (TypeError, ValueError, AttributeError):  # no metadata: no server answered
            continue
    return None


def retry_after(err: object) -> Optional[float]:
    """The wait a refusal asked for (the ``retry-after-ms`` trailer), in seconds."""
    fn = getattr(err, "trailing_metadata", None)
    try:
        for key, value in (fn() if callable(fn) else None) or ():
            if key == "retry-after-ms":
                return max(0.0, int(value) / 1000.0)
    except (TypeError, ValueError, AttributeError):  # no trailers, or not a number: no hint
        return None
    return None


class OperationFailed(B2TFPoseError):
    """An onboarding ended without an object; ``status`` is its final state and
    ``status.error`` says why."""

    def __init__(self, status: FinalState) -> None:
        self.status = status
        why = status.error or status.state
        super().__init__(f"onboarding {status.object_id!r} (operation {status.id}) ended {status.state}: {why}")


class OperationCancelled(OperationFailed):
    """The onboarding was cancelled; nothing of it is stored."""


__all__ = [
    "B2TFPoseError",
    "RpcError",
    "InvalidArgument",
    "NotFound",
    "AlreadyExists",
    "Unauthenticated",
    "ResourceExhausted",
    "DeadlineExceeded",
    "Unavailable",
    "Internal",
    "OperationFailed",
    "OperationCancelled",
    "error_class",
    "from_grpc",
]
