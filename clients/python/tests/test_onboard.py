"""Onboarding through the client: from a path with progress, from a trimesh object with
its texture, from bytes, the operation handle (wait / cancel), and the object calls."""

from __future__ import annotations

from pathlib import Path
from typing import List

import numpy as np
import pytest
import trimesh
from PIL import Image

import b2tfpose
from conftest import SAMPLE_ID, Onboarded


def test_onboard_from_path_reports_progress_to_success(onboarded: Onboarded) -> None:
    info, progress = onboarded.info, onboarded.progress
    assert info.id == SAMPLE_ID and info.templates == 12 * 12 and info.mesh_units == "m"
    # The sample is a 10 x 6 x 16 cm box: its diameter is the space diagonal.
    assert info.diameter_m == pytest.approx(float(np.linalg.norm([0.10, 0.06, 0.16])), rel=1e-3)
    assert progress[0].state == "RUNNING" and progress[-1].state == "SUCCEEDED"
    done = [p.templates_done for p in progress]
    assert done == sorted(done) and progress[-1].templates_done == progress[-1].templates_total == 144
    assert len(set(progress)) == len(progress), "each state is reported once"
    assert progress[-1].object == info


def textured_box_mm() -> trimesh.Trimesh:
    """A 40 x 60 x 80 mm box with a UV texture (four coloured quadrants)."""
    mesh = trimesh.creation.box(extents=[40.0, 60.0, 80.0])
    mesh.unmerge_vertices()  # one UV per face corner
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:32, :32] = (230, 40, 40)
    tex[:32, 32:] = (40, 200, 60)
    tex[32:, :32] = (40, 60, 220)
    tex[32:, 32:] = (240, 220, 30)
    # Each face corner samples a different quadrant: a colourful, non-uniform texture.
    uv = np.tile(np.array([[0.2, 0.2], [0.8, 0.3], [0.7, 0.8]]), (len(mesh.faces), 1))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(tex))
    return mesh


def test_onboard_from_a_textured_trimesh_in_millimetres(client: b2tfpose.Client) -> None:
    mesh = textured_box_mm()
    assert isinstance(mesh.visual, trimesh.visual.TextureVisuals)
    info = client.onboard("trimesh-box", mesh, units="mm", level=0, in_plane=4, replace=True, retry=True)
    # Scaled to metres on the way (GLB is metres): diagonal of 40 x 60 x 80 mm.
    assert info.diameter_m == pytest.approx(float(np.linalg.norm([0.04, 0.06, 0.08])), rel=1e-3)
    assert info.templates == 12 * 4 and info.mesh_units == "m"
    # The texture went along: the stored object holds it (a GLB with an image is larger
    # than the same box untextured would need; the server stores textures as PNG).
    scene = trimesh.Scene([mesh])
    info2 = client.onboard("trimesh-scene", scene, units="mm", level=0, in_plane=1, replace=True, retry=True)
    assert info2.diameter_m == pytest.approx(info.diameter_m, rel=1e-6)
    client.delete_object("trimesh-scene")


def test_trimesh_export_carries_the_texture() -> None:
    from b2tfpose._mesh import mesh_message

    m = mesh_message(textured_box_mm(), "mm")
    assert m.format == "glb" and m.units == "m"
    loaded = trimesh.load(trimesh.util.wrap_as_stream(m.data), file_type="glb", force="mesh")
    assert isinstance(loaded.visual, trimesh.visual.TextureVisuals) and loaded.visual.material is not None
    image = getattr(loaded.visual.material, "baseColorTexture", None) or getattr(loaded.visual.material, "image", None)
    assert image is not None and image.size == (64, 64)
    assert np.allclose(loaded.extents, [0.04, 0.06, 0.08])


def test_onboard_from_bytes_with_resources_and_replace(client: b2tfpose.Client, sample_dir: Path) -> None:
    files = {p.name: p.read_bytes() for p in sample_dir.iterdir()}
    obj = files.pop("sample_box.obj")
    info = client.onboard("bytes-box", obj, format="obj", units="m", resources=files, level=0, in_plane=1, replace=True, retry=True)
    assert info.templates == 12
    with pytest.raises(b2tfpose.AlreadyExists):
        client.onboard("bytes-box", obj, format="obj", units="m", resources=files, level=0, in_plane=1)
    info2 = client.onboard("bytes-box", obj, format="obj", units="m", resources=files, level=0, in_plane=2, replace=True, retry=True)
    assert info2.templates == 24
    client.delete_object("bytes-box")


def test_operation_handle_wait_and_cancel(client: b2tfpose.Client, sample_obj: Path) -> None:
    op = client.onboard("handle-box", sample_obj, units="m", level=0, in_plane=1, wait=False, replace=True, retry=True)
    assert isinstance(op, b2tfpose.Operation) and op.object_id == "handle-box"
    seen: List[b2tfpose.OperationStatus] = []
    info = op.wait(progress=seen.append)
    assert info.id == "handle-box" and seen[-1].state == "SUCCEEDED" and op.status().done
    assert client.operation(op.id).last_status.object == info
    client.delete_object("handle-box")

    # Level 3 (642 views x 12) takes long enough to be cancelled while running.
    big = client.onboard("cancelled-box", sample_obj, units="m", level=3, wait=False, retry=True)
    assert big.last_status.templates_total == 642 * 12
    big.cancel()
    with pytest.raises(b2tfpose.OperationCancelled) as e:
        big.wait(timeout=60)
    assert e.value.status.state == "CANCELLED"
    with pytest.raises(b2tfpose.NotFound):
        client.get_object("cancelled-box")


def test_list_get_delete(client: b2tfpose.Client, onboarded: Onboarded, sample_obj: Path) -> None:
    assert client.get_object(SAMPLE_ID) == onboarded.info
    assert onboarded.info.symmetries == b2tfpose.Symmetries("mesh", discrete=(), continuous=())
    assert SAMPLE_ID in [o.id for o in client.list_objects()]
    client.onboard("to-delete", sample_obj, units="m", level=0, in_plane=1, replace=True, retry=True)
    assert "to-delete" in [o.id for o in client.list_objects()]
    assert client.delete_object("to-delete") is None
    assert "to-delete" not in [o.id for o in client.list_objects()]
    with pytest.raises(b2tfpose.NotFound):
        client.delete_object("to-delete")


def test_pca_settings(client: b2tfpose.Client, sample_obj: Path) -> None:
    from b2tfpose._requests import pca_fields

    assert pca_fields(None) == pca_fields("auto") == {"pca": 0}
    assert pca_fields("off") == {"full_descriptors": True} and pca_fields(24) == {"pca": 24}
    for bad in (0, -1, True, "half", 2.5):
        with pytest.raises(ValueError, match="pca must be"):
            pca_fields(bad)  # type: ignore[arg-type]
    info = client.onboard("pca-off", sample_obj, units="m", level=0, in_plane=1, pca="off", replace=True, retry=True)
    assert isinstance(info, b2tfpose.ObjectInfo) and info.id == "pca-off"
    client.delete_object("pca-off")
    # The embedded backbone's descriptors have 64 values: 65 components cannot be kept.
    with pytest.raises(b2tfpose.InvalidArgument, match="65 components"):
        client.onboard("pca-65", sample_obj, units="m", level=0, in_plane=1, pca=65)


def test_descriptor_codings(client: b2tfpose.Client, sample_obj: Path) -> None:
    # A compact coding is smaller in the store than the exact f16 rows of the same views.
    exact = client.onboard("codings-f16", sample_obj, units="m", level=0, in_plane=2, patch_rows="per-template", replace=True, retry=True)
    compact = client.onboard("codings-pq4", sample_obj, units="m", level=0, in_plane=2, descriptors="pq4", patch_rows="per-template", replace=True, retry=True)
    assert compact.templates == exact.templates and compact.bytes < exact.bytes, (compact, exact)
    # Rows per view: the second in-plane turn shares the first one's rows.
    shared = client.onboard("codings-per-view", sample_obj, units="m", level=0, in_plane=2, patch_rows="per-view", replace=True, retry=True)
    assert shared.templates == exact.templates and shared.bytes < exact.bytes, (shared, exact)
    # The server's default ("auto") with its embedded backbone is rows per view.
    default = client.onboard("codings-default", sample_obj, units="m", level=0, in_plane=2, replace=True, retry=True)
    # (The stored record names the object, so the two differ by the ids' lengths.)
    assert default.templates == exact.templates and abs(default.bytes - shared.bytes) < 100 < exact.bytes - shared.bytes, (default, shared, exact)
    for object_id in ("codings-f16", "codings-pq4", "codings-per-view", "codings-default"):
        client.delete_object(object_id)
    # Refused in the client, before anything is uploaded.
    for bad in ("pq8", "F16 ", 4):
        with pytest.raises(ValueError, match="descriptors must be one of f16, i8, pq2, pq4"):
            client.onboard("codings-bad", sample_obj, units="m", level=0, in_plane=1, descriptors=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="patch_rows must be one of per-template, per-view, auto"):
        client.onboard("codings-bad", sample_obj, units="m", level=0, in_plane=1, patch_rows="per_view")


def test_health(client: b2tfpose.Client) -> None:
    assert client.health() == "SERVING"
    assert client.health("") == "SERVING"
    with pytest.raises(b2tfpose.NotFound):
        client.health("no.such.Service")  # the standard health service's answer


def test_onboard_a_gltf_path_with_external_buffer_and_texture(client: b2tfpose.Client, tmp_path: Path) -> None:
    mesh = textured_box_mm()
    mesh.apply_scale(0.001)
    files = mesh.export(file_type="gltf")  # {"model.gltf": ..., "gltf_buffer_*.bin": ..., texture}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    assert len(files) >= 2
    gltf = tmp_path / "model.gltf"
    from b2tfpose._mesh import mesh_from_path

    m = mesh_from_path(gltf, None)
    assert m.format == "gltf" and sorted(r.name for r in m.resources) == sorted(n for n in files if n != "model.gltf")
    info = client.onboard("gltf-box", gltf, level=0, in_plane=1, replace=True, retry=True)
    assert info.diameter_m == pytest.approx(float(np.linalg.norm([0.04, 0.06, 0.08])), rel=1e-3)
    client.delete_object("gltf-box")


def test_obj_references_are_found(tmp_path: Path) -> None:
    from b2tfpose._mesh import mesh_from_path

    (tmp_path / "m.obj").write_text("mtllib my lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "my lib.mtl").write_text("newmtl a\nmap_Kd -s 1 1 1 -bm 0.5 wood grain.png\nnewmtl b\nmap_Kd wood grain.png\nbump n.png\n")
    (tmp_path / "wood grain.png").write_bytes(b"png")
    (tmp_path / "n.png").write_bytes(b"png2")
    m = mesh_from_path(tmp_path / "m.obj", "mm")
    assert [(r.name, r.data) for r in m.resources] == [("my lib.mtl", (tmp_path / "my lib.mtl").read_bytes()), ("wood grain.png", b"png"), ("n.png", b"png2")]
    assert m.units == "mm" and m.format == "obj"
    with pytest.raises(ValueError, match="units"):
        mesh_from_path(tmp_path / "m.obj", None)
    (tmp_path / "my lib.mtl").write_text("map_Kd textures/w.png\n")
    with pytest.raises(ValueError, match="plain names"):
        mesh_from_path(tmp_path / "m.obj", "mm")
    (tmp_path / "my lib.mtl").write_text("map_Kd missing.png\n")
    with pytest.raises(FileNotFoundError, match="missing.png"):
        mesh_from_path(tmp_path / "m.obj", "mm")


def test_ply_texture_file_is_sent(tmp_path: Path) -> None:
    from b2tfpose._mesh import mesh_from_path

    header = "ply\nformat binary_little_endian 1.0\ncomment TextureFile tex.png\nelement vertex 0\nproperty float x\nend_header\n"
    (tmp_path / "m.ply").write_bytes(header.encode() + b"\x00\xff")  # binary body after the header
    (tmp_path / "tex.png").write_bytes(b"texture")
    m = mesh_from_path(tmp_path / "m.ply", "mm")
    assert m.format == "ply" and [(r.name, r.data) for r in m.resources] == [("tex.png", b"texture")]
