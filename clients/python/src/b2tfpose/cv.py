"""Drawing poses with OpenCV (``pip install b2tfpose[cv]``): the object's axes and its
projected outline (from a mesh) or 3-D bounding box."""

from __future__ import annotations

from typing import Any, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ._convert import IntrinsicsInput, K_matrix
from ._mesh import UNITS_TO_M
from ._pose import Pose
from ._types import Result

Color = Tuple[int, int, int]
Shape = Union[None, Sequence[float], npt.NDArray[Any], Any]

# The 12 edges of a box by corner index, corners ordered as itertools.product([-1, 1], 3).
_BOX_EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]


def _cv2() -> Any:
    try:
        import cv2
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("b2tfpose.cv needs OpenCV: pip install 'b2tfpose[cv]'") from e
    return cv2


def project(points: npt.ArrayLike, pose: Pose, K: IntrinsicsInput) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Pixel coordinates (N x 2) and camera depths (N) of object-frame points (metres)."""
    P = pose.transform(points)
    z = P[:, 2]
    uvw = P @ K_matrix(K).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


def box_corners(size_or_points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The 8 corners of a box: from its size (dx, dy, dz) centred at the origin, from 8
    corner points as they are, or the axis-aligned bounds of any N x 3 points."""
    a = np.asarray(size_or_points, dtype=np.float64)
    if a.shape == (3,):
        lo, hi = -a / 2, a / 2
    elif a.ndim == 2 and a.shape[1] == 3 and a.shape[0] == 8:
        return a
    elif a.ndim == 2 and a.shape[1] == 3 and a.shape[0] > 0:
        lo, hi = a.min(axis=0), a.max(axis=0)
    else:
        raise ValueError(f"box: expected (dx, dy, dz), 8 corners or N x 3 points, got shape {a.shape}")
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def _mesh_arrays(mesh: Any, units: str) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices (metres) and triangles of a trimesh object or a mesh file."""
    import os

    if isinstance(mesh, (str, os.PathLike)):
        import trimesh

        mesh = trimesh.load(os.fspath(mesh), force="mesh")
    if hasattr(mesh, "to_geometry"):  # a Scene: flatten with its node transforms
        mesh = mesh.to_geometry()
    elif hasattr(mesh, "dump") and not hasattr(mesh, "faces"):
        mesh = mesh.dump(concatenate=True)
    V = np.asarray(mesh.vertices, dtype=np.float64) * UNITS_TO_M[units]
    F = np.asarray(mesh.faces, dtype=np.int64)
    return V, F


def outline_mask(vertices: npt.ArrayLike, faces: npt.ArrayLike, pose: Pose, K: IntrinsicsInput, shape: Tuple[int, int]) -> npt.NDArray[np.uint8]:
    """The object's silhouette (255 inside) of the given image size: every triangle in
    front of the camera filled."""
    cv2 = _cv2()
    uv, z = project(vertices, pose, K)
    F = np.asarray(faces, dtype=np.int64)
    keep = np.all(z[F] > 1e-6, axis=1)
    mask = np.zeros(shape, dtype=np.uint8)
    tris = np.round(uv[F[keep]] * 16).astype(np.int32)  # 4 fractional bits
    if len(tris):
        cv2.fillPoly(mask, list(tris), 255, lineType=cv2.LINE_8, shift=4)
    return mask


def draw_pose(
    image: npt.NDArray[Any],
    pose: Union[Pose, Result],
    K: IntrinsicsInput,
    mesh_or_box: Shape = None,
    *,
    units: str = "m",
    axis_length: Optional[float] = None,
    color: Color = (0, 255, 0),
    thickness: int = 2,
    bgr: bool = False,
    axes: bool = True,
    copy: bool = True,
) -> npt.NDArray[np.uint8]:
    """Draws ``pose`` on ``image`` (HxWx3 uint8): the object's x/y/z axes in red / green /
    blue from its origin, and, given ``mesh_or_box``, the projected outline of a mesh (a
    ``trimesh`` object or a mesh path) or the edges of a box (size (dx, dy, dz) centred at
    the origin, 8 corners, or N x 3 points whose bounds are drawn), in ``color``.

    ``units``: of the mesh / box (poses are metres). ``bgr``: the image is OpenCV's BGR,
    so colours are swapped to match (``color`` is always given as RGB). ``axis_length``
    defaults to half the box's / mesh's largest side, else 5 cm; ``axes=False`` leaves
    them out. Returns the drawn image (a copy unless ``copy=False``)."""
    cv2 = _cv2()
    if isinstance(pose, Result):
        if pose.pose is None:
            raise ValueError(f"draw_pose: the result has no pose ({pose.reason})")
        pose = pose.pose
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"draw_pose: expected an HxWx3 uint8 image, got {image.shape} {image.dtype}")
    out: npt.NDArray[np.uint8] = image.copy() if copy else image

    def c(rgb: Color) -> Color:
        return (rgb[2], rgb[1], rgb[0]) if bgr else rgb

    extent: Optional[float] = None
    if mesh_or_box is not None:
        if isinstance(mesh_or_box, (list, tuple, np.ndarray)):
            corners = box_corners(np.asarray(mesh_or_box, dtype=np.float64) * UNITS_TO_M[units])
            extent = float(np.max(corners.max(axis=0) - corners.min(axis=0)))
            uv, z = project(corners, pose, K)
            for i, j in _BOX_EDGES:
                if z[i] > 1e-6 and z[j] > 1e-6:
                    p1 = tuple(int(round(v)) for v in uv[i])
                    p2 = tuple(int(round(v)) for v in uv[j])
                    cv2.line(out, p1, p2, c(color), thickness, cv2.LINE_AA)
        else:
            V, F = _mesh_arrays(mesh_or_box, units)
            extent = float(np.max(V.max(axis=0) - V.min(axis=0)))
            mask = outline_mask(V, F, pose, K, out.shape[:2])
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(out, contours, -1, c(color), thickness, cv2.LINE_AA)
    if not axes:
        return out
    length = axis_length if axis_length is not None else (extent / 2 if extent else 0.05)
    axis_points = np.array([[0, 0, 0], [length, 0, 0], [0, length, 0], [0, 0, length]], dtype=np.float64)
    uv, z = project(axis_points, pose, K)
    if np.all(z > 1e-6):
        o = tuple(int(round(v)) for v in uv[0])
        for i, rgb in ((1, (255, 0, 0)), (2, (0, 255, 0)), (3, (0, 0, 255))):
            cv2.line(out, o, tuple(int(round(v)) for v in uv[i]), c(rgb), thickness, cv2.LINE_AA)
    return out
