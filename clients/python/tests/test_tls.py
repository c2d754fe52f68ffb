"""TLS with an API key: a self-signed certificate made here, the server serving both ports
over it, clients trusting it (sync and async), and the failures around it."""

from __future__ import annotations

import asyncio
import datetime
import ipaddress
from pathlib import Path
from typing import Iterator, Tuple

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

import b2tfpose
from conftest import SAMPLE_ID, Onboarded, Scene, assert_same_pose
from servers import Server

KEY = "tls-key-1"


def self_signed(dir: Path) -> Tuple[Path, Path]:
    """A certificate for localhost / 127.0.0.1 and its key, as PEM files."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "localhost")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = dir / "cert.pem", dir / "key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    return cert_path, key_path


@pytest.fixture(scope="module")
def tls_server(work: Path, store: str, onboarded: Onboarded) -> Iterator[Tuple[Server, Path]]:
    cert, key = self_signed(work)
    keys = work / "tls-keys.txt"
    keys.write_text(KEY + "\n")
    s = Server(store, work / "tls.log", ["--tls-cert", str(cert), "--tls-key", str(key), "--api-keys-file", str(keys)], ca_cert=cert)
    assert s.tls and s.grpc_url.startswith("grpcs://")
    yield s, cert
    s.stop()


def test_tls_with_key_estimates_like_plaintext(tls_server: Tuple[Server, Path], scene: Scene, cli_mask_pose: b2tfpose.Pose) -> None:
    s, cert = tls_server
    # ca_cert as a path, as PEM bytes; the grpcs:// scheme or tls=True.
    with b2tfpose.Client(s.address, api_key=KEY, ca_cert=cert) as c:
        assert c.health() == "SERVING"
        assert SAMPLE_ID in [o.id for o in c.list_objects()]
        [r] = c.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
        assert r.pose is not None
        assert_same_pose(r.pose, cli_mask_pose)
    with b2tfpose.Client(f"grpcs://localhost:{s.address.rsplit(':', 1)[1]}", api_key=KEY, ca_cert=cert.read_bytes()) as c:
        assert c.get_object(SAMPLE_ID).id == SAMPLE_ID

    async def aio() -> None:
        async with b2tfpose.AsyncClient(s.grpc_url, api_key=KEY, ca_cert=str(cert)) as c:
            assert (await c.get_object(SAMPLE_ID)).id == SAMPLE_ID

    asyncio.run(aio())


def test_tls_failures(tls_server: Tuple[Server, Path], work: Path) -> None:
    s, cert = tls_server
    with b2tfpose.Client(s.address, ca_cert=cert) as c, pytest.raises(b2tfpose.Unauthenticated):
        c.list_objects()
    # Plaintext to a TLS port, and TLS without trusting the self-signed certificate.
    with b2tfpose.Client(s.address, timeout=5, retry=b2tfpose.NO_RETRY) as c, pytest.raises(b2tfpose.Unavailable):
        c.health()
    with b2tfpose.Client(s.address, tls=True, timeout=5, retry=b2tfpose.NO_RETRY) as c, pytest.raises(b2tfpose.Unavailable):
        c.health()
    (work / "other-cert").mkdir(exist_ok=True)
    other, _ = self_signed(work / "other-cert")
    with b2tfpose.Client(s.address, ca_cert=other, timeout=5, retry=b2tfpose.NO_RETRY) as c, pytest.raises(b2tfpose.Unavailable):
        c.health()
    with pytest.raises(ValueError, match="plain"):
        b2tfpose.Client(f"grpc://{s.address}", ca_cert=cert)
