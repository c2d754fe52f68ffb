"""The package as users get it: the sdist and wheel (built by scripts/build.sh, or here),
the wheel installed into a fresh venv running the README's quickstart, and the type stubs
passing mypy --strict on the examples."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path
from typing import Iterator, Tuple

import cv2
import pytest

from conftest import Scene
from servers import Server

HERE = Path(__file__).resolve().parents[1]  # clients/python


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Tuple[Path, Path]:
    """(sdist, wheel): from $B2TFPOSE_DIST when scripts/test.sh built them, else built now."""
    given = os.environ.get("B2TFPOSE_DIST")
    folder = Path(given) if given else tmp_path_factory.mktemp("dist")
    if not given:
        subprocess.run(["bash", str(HERE / "scripts/build.sh"), str(folder)], check=True, capture_output=True, env={**os.environ, "PYTHON": sys.executable})
    [sdist] = sorted(folder.glob("b2tfpose-*.tar.gz"))
    [wheel] = sorted(folder.glob("b2tfpose-*.whl"))
    return sdist, wheel


def test_wheel_holds_generated_stubs_and_sdist_the_proto(dist: Tuple[Path, Path]) -> None:
    sdist, wheel = dist
    assert wheel.name.endswith("-py3-none-any.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for n in ("pose_service_pb2.py", "pose_service_pb2.pyi", "pose_service_pb2_grpc.py", "pose_service_pb2_grpc.pyi", "__init__.py"):
        assert f"b2tfpose/v1/{n}" in names
    assert {"b2tfpose/py.typed", "b2tfpose/client.py", "b2tfpose/aio.py", "b2tfpose/_track.py", "b2tfpose/cv.py", "b2tfpose/bop.py"} <= names
    meta = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("METADATA"))).decode()
    assert "Requires-Python: >=3.9" in meta and "Provides-Extra: mesh" in meta and "Provides-Extra: cv" in meta and "Provides-Extra: all" in meta
    with tarfile.open(sdist) as t:
        members = t.getnames()
    assert any(m.endswith("proto/b2tfpose/v1/pose_service.proto") for m in members)
    assert not any("/src/b2tfpose/v1/" in m for m in members), "generated code is never shipped as source"
    # The proto in the sdist is the repository's.
    with tarfile.open(sdist) as t:
        member = next(m for m in t.getmembers() if m.name.endswith("proto/b2tfpose/v1/pose_service.proto"))
        f = t.extractfile(member)
        assert f is not None and f.read() == (HERE.parents[1] / "proto/b2tfpose/v1/pose_service.proto").read_bytes()


def quickstart() -> str:
    text = (HERE / "README.md").read_text()
    m = re.search(r"<!-- quickstart -->\s*```python\n(.*?)```\s*<!-- /quickstart -->", text, re.S)
    assert m, "the README's quickstart block"
    return m.group(1)


@pytest.fixture(scope="module")
def fresh_venv(tmp_path_factory: pytest.TempPathFactory, dist: Tuple[Path, Path]) -> Iterator[Path]:
    venv = tmp_path_factory.mktemp("fresh") / "venv"
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    py = venv / "bin/python"
    p = subprocess.run([str(py), "-m", "pip", "install", "--quiet", f"{dist[1]}[all]"], capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
    yield py
    shutil.rmtree(venv, ignore_errors=True)


def test_readme_quickstart_in_a_fresh_venv(fresh_venv: Path, server: Server, scene: Scene, sample_dir: Path, tmp_path: Path) -> None:
    code = quickstart()
    assert len(code.strip().splitlines()) < 10
    for name in ("rgb.png", "mask.png"):
        (tmp_path / name).write_bytes((scene.dir / name).read_bytes())
    shutil.copytree(sample_dir, tmp_path / "sample")
    (tmp_path / "quickstart.py").write_text(code.replace("localhost:50051", server.address))
    p = subprocess.run([str(fresh_venv), "quickstart.py"], cwd=tmp_path, capture_output=True, text=True, timeout=180, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert p.returncode == 0, p.stdout + p.stderr
    numbers = [float(x) for x in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", p.stdout)]
    assert len(numbers) == 13  # R (9), t (3), score
    assert abs(numbers[11] - 0.5) < 0.01  # the scene is 0.5 m away
    overlay = cv2.imread(str(tmp_path / "overlay.png"))
    assert overlay is not None and overlay.shape == (240, 320, 3)
    assert ((overlay[..., 1] == 255) & (overlay[..., 0] < 50) & (overlay[..., 2] < 50)).sum() > 100  # the green outline
    # The installed package is the wheel's, not this source tree.
    where = subprocess.run([str(fresh_venv), "-c", "import b2tfpose, sys; print(b2tfpose.__file__)"], capture_output=True, text=True, cwd=tmp_path)
    assert str(fresh_venv.parent.parent) in where.stdout


def test_mypy_strict_on_the_examples_and_the_package() -> None:
    """The examples type-check against the installed package and its generated stubs; the
    package itself too. mypy no longer targets 3.9, so 3.9's grammar is checked by ast."""
    mypy = [sys.executable, "-m", "mypy", "--strict", "--no-incremental"]
    p = subprocess.run([*mypy, str(HERE / "examples")], capture_output=True, text=True, cwd=HERE, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "Success: no issues found in 5 source files" in p.stdout
    p = subprocess.run([*mypy, "-p", "b2tfpose"], capture_output=True, text=True, cwd=HERE / "tests", timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    import ast

    for path in [*(HERE / "src/b2tfpose").glob("*.py"), *(HERE / "examples").glob("*.py")]:
        ast.parse(path.read_text(), str(path), feature_version=(3, 9))
