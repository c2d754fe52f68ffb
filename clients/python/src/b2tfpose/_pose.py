"""`Pose`: a rigid transform T_cam_obj (object frame -> camera frame, metres), with the
forms users want: R, t, T, the quaternion, and OpenCV's rvec / tvec."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def rotation_to_rvec(R: FloatArray) -> FloatArray:
    """Axis-angle (OpenCV's Rodrigues vector, 3x1) of a rotation matrix; the same as
    ``cv2.Rodrigues(R)[0]`` without needing OpenCV."""
    cos = max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0))
    angle = math.acos(cos)
    if angle < 1e-12:
        return np.zeros((3, 1))
    if math.pi - angle < 1e-6:
        # Near 180 degrees the antisymmetric part vanishes: take the axis from R + I.
        M = (R + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(M)))
        axis = M[:, i] / math.sqrt(max(M[i, i], 1e-300))
        return (axis / np.linalg.norm(axis) * angle).reshape(3, 1)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return (w / (2.0 * math.sin(angle)) * angle).reshape(3, 1)


def rvec_to_rotation(rvec: npt.ArrayLike) -> FloatArray:
    """Rotation matrix of an axis-angle vector (inverse of :func:`rotation_to_rvec`)."""
    v = np.asarray(rvec, dtype=np.float64).reshape(3)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R: FloatArray = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)
    return R


def rotation_to_quaternion_wxyz(R: FloatArray) -> FloatArray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix."""
    tr = float(np.trace(R))
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    out = np.array(q, dtype=np.float64)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0 else -out


class Pose:
    """T_cam_obj: ``x_cam = R @ x_obj + t``, lengths in metres (BOP's cam_R_m2c /
    cam_t_m2c, with t in metres rather than millimetres)."""

    __slots__ = ("_R", "_t")

    def __init__(self, R: npt.ArrayLike, t: npt.ArrayLike) -> None:
        R_ = np.asarray(R, dtype=np.float64).reshape(3, 3).copy()
        t_ = np.asarray(t, dtype=np.float64).reshape(3).copy()
        if not (np.all(np.isfinite(R_)) and np.all(np.isfinite(t_))):
            raise ValueError("Pose: R and t must be finite")
        R_.flags.writeable = False
        t_.flags.writeable = False
        self._R = R_
        self._t = t_

    @classmethod
    def from_matrix(cls, T: npt.ArrayLike) -> "Pose":
        """From a 4x4 homogeneous matrix."""
        M = np.asarray(T, dtype=np.float64).reshape(4, 4)
        return cls(M[:3, :3], M[:3, 3])

    @classmethod
    def from_rvec_tvec(cls, rvec: npt.ArrayLike, tvec: npt.ArrayLike) -> "Pose":
        """From OpenCV's (rvec, tvec), e.g. ``cv2.solvePnP``'s (tvec in metres)."""
        return cls(rvec_to_rotation(rvec), np.asarray(tvec, dtype=np.float64).reshape(3))

    @property
    def R(self) -> FloatArray:
        """Rotation, 3x3 (read-only array)."""
        return self._R

    @property
    def t(self) -> FloatArray:
        """Translation, metres, shape (3,) (read-only array)."""
        return self._t

    @property
    def t_mm(self) -> FloatArray:
        """Translation in millimetres (BOP's unit)."""
        return self._t * 1000.0

    @property
    def T(self) -> FloatArray:
        """The 4x4 homogeneous matrix (a new array)."""
        M = np.eye(4)
        M[:3, :3] = self._R
        M[:3, 3] = self._t
        return M

    @property
    def quaternion_wxyz(self) -> FloatArray:
        """The rotation as a unit quaternion (w, x, y, z), w >= 0."""
        return rotation_to_quaternion_wxyz(self._R)

    @property
    def rvec(self) -> FloatArray:
        """OpenCV's rotation vector (3x1 float64), as ``cv2.Rodrigues(R)[0]``."""
        return rotation_to_rvec(self._R)

    @property
    def tvec(self) -> FloatArray:
        """OpenCV's translation vector (3x1 float64, metres)."""
        return self._t.reshape(3, 1).copy()

    def inverse(self) -> "Pose":
        """T_obj_cam."""
        return Pose(self._R.T, -self._R.T @ self._t)

    def __matmul__(self, other: "Pose") -> "Pose":
        return Pose(self._R @ other._R, self._R @ other._t + self._t)

    def transform(self, points: npt.ArrayLike) -> FloatArray:
        """Object-frame points (N x 3, metres) in the camera frame."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out: FloatArray = P @ self._R.T + self._t
        return out

    def rotation_error_deg(self, other: "Pose") -> float:
        """Geodesic angle between the two rotations, degrees."""
        c = (float(np.trace(self._R.T @ other._R)) - 1.0) / 2.0
        return math.degrees(math.acos(max(-1.0, min(1.0, c))))

    def translation_error_m(self, other: "Pose") -> float:
        """Distance between the two translations, metres."""
        return float(np.linalg.norm(self._t - other._t))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Pose) and bool(np.array_equal(self._R, other._R) and np.array_equal(self._t, other._t))

    def __hash__(self) -> int:
        return hash((self._R.tobytes(), self._t.tobytes()))

    def __repr__(self) -> str:
        q = ", ".join(f"{v:.4f}" for v in self.quaternion_wxyz)
        t = ", ".join(f"{v:.4f}" for v in self._t)
        return f"Pose(t=[{t}] m, quaternion_wxyz=[{q}])"
