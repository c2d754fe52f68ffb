"""Connection settings shared by both clients: the address, TLS credentials, the API key
as call metadata, channel options, and the standard health check's two tiny messages."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple, Union

import grpc

from ._request_id import current as current_request_id
from ._retry import RetryPolicy

CaCert = Union[bytes, str, "os.PathLike[str]"]
Metadata = Tuple[Tuple[str, str], ...]
ChannelOptions = List[Tuple[str, Union[str, int]]]

SERVICE = "b2tfpose.v1.PoseService"
HEALTH_CHECK = "/grpc.health.v1.Health/Check"
SERVING_STATUS = {0: "UNKNOWN", 1: "SERVING", 2: "NOT_SERVING", 3: "SERVICE_UNKNOWN"}


def _read_pem(ca: CaCert) -> bytes:
    """PEM bytes, from bytes, a path, or a string that is either a path or PEM text."""
    if isinstance(ca, bytes):
        return ca
    if isinstance(ca, str) and "-----BEGIN" in ca:
        return ca.encode()
    return Path(ca).read_bytes()


@dataclass(frozen=True)
class Settings:
    """Everything a client needs to open its channel and make calls."""

    target: str
    credentials: Optional[grpc.ChannelCredentials]
    options: ChannelOptions
    metadata: Metadata
    timeout: Optional[float]
    retry: RetryPolicy

    @classmethod
    def make(
        cls,
        address: str,
        api_key: Optional[str],
        tls: Optional[bool],
        ca_cert: Optional[CaCert],
        server_name: Optional[str],
        timeout: Optional[float],
        retry: Optional[RetryPolicy],
        options: Optional[Sequence[Tuple[str, Union[str, int]]]],
    ) -> "Settings":
        """``address`` is ``host:port``, ``grpc://host:port`` (plain) or
        ``grpcs://host:port`` (TLS). TLS is on for grpcs://, ``tls=True`` or a
        ``ca_cert`` (the PEM to trust, e.g. a self-signed server certificate; without it
        the system roots are used)."""
        target = address
        scheme_tls: Optional[bool] = None
        for prefix, is_tls in (("grpcs://", True), ("https://", True), ("grpc://", False), ("http://", False)):
            if address.startswith(prefix):
                target, scheme_tls = address[len(prefix) :].rstrip("/"), is_tls
                break
        if not target or "/" in target:
            raise ValueError(f"address {address!r}: expected host:port, grpc://host:port or grpcs://host:port")
        if scheme_tls is False and (tls or ca_cert is not None):
            raise ValueError(f"address {address!r} is plain grpc:// but TLS was asked for (tls / ca_cert)")
        use_tls = bool(scheme_tls) or bool(tls) or ca_cert is not None
        creds = grpc.ssl_channel_credentials(root_certificates=_read_pem(ca_cert) if ca_cert is not None else None) if use_tls else None
        if api_key is not None and (not api_key or any(c in api_key for c in "\r\n")):
            raise ValueError("api_key must be a non-empty single line")
        opts: ChannelOptions = [
            # The server bounds messages (--max-body-mb); the client does not add its own.
            ("grpc.max_send_message_length", -1),
            ("grpc.max_receive_message_length", -1),
            ("grpc.primary_user_agent", "b2tfpose-python"),
        ]
        if server_name:
            opts.append(("grpc.ssl_target_name_override", server_name))
        opts.extend(options or [])
        metadata: Metadata = (("authorization", f"Bearer {api_key}"),) if api_key else ()
        return cls(target, creds, opts, metadata, timeout, retry or RetryPolicy())

    def call_metadata(self) -> Metadata:
        """The metadata of a call: the API key, and the caller's request id if one is set
        (``b2tfpose.request_id``)."""
        rid = current_request_id()
        return self.metadata + (("x-request-id", rid),) if rid else self.metadata

    def open_sync(self) -> grpc.Channel:
        if self.credentials is not None:
            return grpc.secure_channel(self.target, self.credentials, options=self.options)
        return grpc.insecure_channel(self.target, options=self.options)

    def open_aio(self) -> grpc.aio.Channel:
        if self.credentials is not None:
            return grpc.aio.secure_channel(self.target, self.credentials, options=self.options)
        return grpc.aio.insecure_channel(self.target, options=self.options)


# grpc.health.v1 HealthCheckRequest / HealthCheckResponse are one field each; encoding them
# by hand spares a dependency on grpcio-health-checking.


def encode_health_request(service: str) -> bytes:
    """HealthCheckRequest{service} on the wire: field 1, length-delimited."""
    data = service.encode()
    return b"\x0a" + _varint(len(data)) + data if data else b""


def decode_health_response(data: bytes) -> str:
    """The ServingStatus name of a HealthCheckResponse (field 1, varint)."""
    p, status = 0, 0
    while p < len(data):
        key, p = _read_varint(data, p)
        if key == 0x08:
            status, p = _read_varint(data, p)
        elif key & 7 == 2:
            n, p = _read_varint(data, p)
            p += n
        elif key & 7 == 0:
            _, p = _read_varint(data, p)
        else:
            break
    return SERVING_STATUS.get(status, f"STATUS_{status}")


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _read_varint(data: bytes, p: int) -> Tuple[int, int]:
    n, shift = 0, 0
    while p < len(data):
        b = data[p]
        p += 1
        n |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            break
    return n, p


def identity(b: bytes) -> bytes:
    return b
