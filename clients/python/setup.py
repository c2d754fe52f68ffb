"""Build hook: the gRPC stubs are generated from the repository's proto at build time.

`proto/b2tfpose/v1/pose_service.proto` at the repository root is the single source of
truth; nothing generated is kept in git. Building from `clients/python/` finds it at
`../../proto`; an sdist carries a copy in `proto/` (copied here when the sdist is made), so
a wheel can be built from the sdist alone. The generated modules land in the build tree as
the subpackage `b2tfpose.v1` (the proto's own path), with mypy-protobuf's .pyi stubs.
"""

from __future__ import annotations

import shutil
import stat
import sys
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = Path(__file__).resolve().parent
PROTO_REL = Path("b2tfpose/v1/pose_service.proto")
REPO_PROTO_ROOT = HERE.parent.parent / "proto"  # building inside the repository
LOCAL_PROTO_ROOT = HERE / "proto"  # building from an unpacked sdist


def proto_root() -> Path:
    """The repository's proto when present (always fresh), else the sdist's copy."""
    for root in (REPO_PROTO_ROOT, LOCAL_PROTO_ROOT):
        if (root / PROTO_REL).is_file():
            return root
    raise SystemExit(f"b2tfpose build: {PROTO_REL} found neither in {REPO_PROTO_ROOT} nor in {LOCAL_PROTO_ROOT}")


def copy_proto_here() -> None:
    """Refreshes `proto/` beside this file from the repository (for the sdist)."""
    if (REPO_PROTO_ROOT / PROTO_REL).is_file():
        dest = LOCAL_PROTO_ROOT / PROTO_REL
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(REPO_PROTO_ROOT / PROTO_REL, dest)


def plugin(tmp: Path, name: str, func: str) -> Path:
    """An executable protoc plugin running mypy-protobuf with this interpreter: the build
    environment's scripts folder is not always on PATH."""
    path = tmp / f"protoc-gen-{name}"
    path.write_text(f"#!{sys.executable}\nimport sys\nfrom mypy_protobuf.main import {func}\nsys.exit({func}())\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def generate(out: Path) -> None:
    from grpc_tools import protoc  # build requirement

    root = proto_root()
    include = Path(protoc.__file__).parent / "_proto"  # protobuf's well-known types
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        args = [
            "grpc_tools.protoc",
            f"-I{root}",
            f"-I{include}",
            f"--python_out={out}",
            f"--grpc_python_out={out}",
            f"--plugin=protoc-gen-mypy={plugin(tmp, 'mypy', 'main')}",
            f"--plugin=protoc-gen-mypy_grpc={plugin(tmp, 'mypy_grpc', 'grpc')}",
            f"--mypy_out={out}",
            f"--mypy_grpc_out={out}",
            str(root / PROTO_REL),
        ]
        if protoc.main(args) != 0:
            raise SystemExit(f"b2tfpose build: protoc failed on {root / PROTO_REL}")
    pkg = out / PROTO_REL.parent
    (pkg / "__init__.py").write_text('"""Generated from proto/b2tfpose/v1/pose_service.proto at build time."""\n')


class BuildPyWithProto(build_py):
    def run(self) -> None:
        super().run()
        generate(Path(self.build_lib))


class SdistWithProto(sdist):
    def run(self) -> None:
        copy_proto_here()
        super().run()


setup(cmdclass={"build_py": BuildPyWithProto, "sdist": SdistWithProto})
