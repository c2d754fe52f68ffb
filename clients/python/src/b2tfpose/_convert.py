"""Inputs as users hold them -> the request messages: images (numpy RGB/BGR, encoded
bytes, paths), intrinsics (3x3 or fx, fy, cx, cy), detections (masks, RLE, boxes), and
the frames of a tracking stream."""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import masks as _masks
from .v1 import pose_service_pb2 as pb

PathLike = Union[str, "os.PathLike[str]"]
ImageInput = Union[npt.NDArray[Any], bytes, bytearray, memoryview, PathLike]
IntrinsicsInput = Union[npt.ArrayLike, Sequence[float]]
MaskInput = Union[npt.NDArray[Any], bytes, PathLike]
BoxInput = Sequence[float]


@dataclass(frozen=True, eq=False)  # masks are arrays: identity, not element-wise, equality
class Detection:
    """One detection of one object: a mask (numpy bool/uint8 HxW, PNG bytes or a PNG
    path), or an RLE (COCO dict, uncompressed or compressed counts), and/or a box
    ``(x, y, width, height)`` in pixels — a box alone makes the server propose several
    masks inside it and keep the one whose pose fills the box best. ``score`` is the detector's confidence in [0, 1] (1 when unset)."""

    object_id: str
    mask: Optional[MaskInput] = None
    rle: Optional[Mapping[str, Any]] = None
    box: Optional[BoxInput] = None
    score: Optional[float] = None

    def __post_init__(self) -> None:
        if self.mask is not None and self.rle is not None:
            raise ValueError("Detection: give mask or rle, not both")
        if self.mask is None and self.rle is None and self.box is None:
            raise ValueError(f"Detection of {self.object_id!r}: give a mask, an rle or a box")


DetectionInput = Union[Detection, Mapping[str, Any]]

# Keys accepted in plain dicts, with the aliases detectors write (COCO/CNOS: bbox,
# segmentation).
_ALIASES = {"bbox": "box", "segmentation": "rle", "mask_rle": "rle", "id": "object_id", "obj_id": "object_id"}


def as_detection(d: DetectionInput) -> Detection:
    if isinstance(d, Detection):
        return d
    if not isinstance(d, Mapping):
        raise TypeError(f"a detection must be a b2tfpose.Detection or a dict, not {type(d).__name__}")
    kw = {}
    for k, v in d.items():
        key = _ALIASES.get(k, k)
        if key not in ("object_id", "mask", "rle", "box", "score"):
            raise ValueError(f"detection key {k!r}: expected object_id, mask, rle, box (bbox) or score")
        kw[key] = v
    if "object_id" not in kw:
        raise ValueError("a detection dict needs 'object_id'")
    obj = kw.pop("object_id")
    return Detection(str(obj), **kw)


# ---------------------------------------------------------------------------- frames


@dataclass(frozen=True, eq=False)  # images are arrays: identity, not element-wise, equality
class TrackFrame:
    """One video frame for :meth:`b2tfpose.Client.track`.

    ``image`` and ``detections`` as :meth:`~b2tfpose.Client.estimate` takes them (numpy
    RGB / BGR, PNG / JPEG bytes or a path; :class:`Detection` objects or dicts). ``K``: 3x3
    or (fx, fy, cx, cy); None takes the ``K`` given to ``track()``. ``detections`` may be
    empty: once an object is tracked it is followed without them; a detection that no track
    of its object overlaps starts a track, one over a lost track re-initialises it.
    ``frame_index``: the frame's number, above the last frame's (None: the next).
    ``objects``: instead of detections, ids the server's detector looks for in this frame,
    each only while no track of it was followed into the last frame (a new or lost object
    is found, a tracked one costs no search). ``depth`` (RGB-D): the frame's depth image
    registered to it, as :meth:`~b2tfpose.Client.estimate` takes it (uint16 with
    ``depth_scale`` millimetres per unit, float metres, or a 16-bit PNG's bytes or path):
    tracks are then fitted to the measured surface (``TrackedObject.depth_fit``) and lost
    where it refutes them."""

    image: ImageInput
    K: Optional[IntrinsicsInput] = None
    detections: Sequence[DetectionInput] = ()
    frame_index: Optional[int] = None
    objects: Sequence[str] = ()
    depth: Optional[DepthInput] = None
    depth_scale: Optional[float] = None


FrameInput = Union[TrackFrame, Mapping[str, Any], Tuple[Any, ...], ImageInput]

_FRAME_KEYS = {"image": "image", "K": "K", "intrinsics": "K", "detections": "detections", "frame_index": "frame_index", "objects": "objects", "depth": "depth", "depth_scale": "depth_scale"}


def as_track_frame(f: FrameInput, K: Optional[IntrinsicsInput]) -> TrackFrame:
    """A frame in any accepted form as a :class:`TrackFrame` whose ``K`` is set: a
    TrackFrame, a dict with its keys (``intrinsics`` for ``K``), a tuple ``(image, K)`` or
    ``(image, K, detections)``, or a bare image (then ``K`` is the call's)."""
    if isinstance(f, TrackFrame):
        frame = f
    elif isinstance(f, Mapping):
        kw: Dict[str, Any] = {}
        for k, v in f.items():
            if k not in _FRAME_KEYS:
                raise ValueError(f"frame key {k!r}: expected image, K (intrinsics), detections, frame_index, objects, depth or depth_scale")
            kw[_FRAME_KEYS[k]] = v
        if "image" not in kw:
            raise ValueError("a frame dict needs 'image'")
        frame = TrackFrame(**kw)
    elif isinstance(f, tuple):
        if not 2 <= len(f) <= 3:
            raise ValueError(f"a frame tuple is (image, K) or (image, K, detections), not {len(f)} values")
        frame = TrackFrame(*f)
    elif isinstance(f, (np.ndarray, bytes, bytearray, memoryview, str, os.PathLike)):
        frame = TrackFrame(f)
    else:
        raise TypeError(f"a frame must be a b2tfpose.TrackFrame, a dict, an (image, K[, detections]) tuple or an image, not {type(f).__name__}")
    dets = frame.detections
    if dets is None:
        frame = replace(frame, detections=())
    elif isinstance(dets, (Mapping, str, bytes)) or not isinstance(dets, Sequence):
        raise TypeError("a frame's detections: a list of b2tfpose.Detection (or dicts)")
    if isinstance(frame.objects, (str, bytes)) or not isinstance(frame.objects, Sequence) or not all(isinstance(o, str) for o in frame.objects):
        raise TypeError("a frame's objects: a list of object ids (str)")
    if frame.objects and frame.detections:
        raise ValueError("a frame gives detections or objects, not both")
    if frame.frame_index is not None and (isinstance(frame.frame_index, bool) or not isinstance(frame.frame_index, (int, np.integer)) or frame.frame_index < 0):
        raise ValueError(f"frame_index must be an integer >= 0, not {frame.frame_index!r}")
    if frame.K is None:
        if K is None:
            raise ValueError("a frame without K: give K in the frame or to track(K=...)")
        frame = replace(frame, K=K)
    return frame


# ---------------------------------------------------------------------------- images


def _is_path(x: object) -> bool:
    return isinstance(x, (str, os.PathLike))


def encoded_size(data: bytes) -> Tuple[int, int]:
    """(width, height) from a PNG or JPEG header: the intrinsics message must carry the
    image's size, so it is read here rather than decoding the image."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] == b"\xff\xd8":
        p = 2
        while p + 4 <= len(data):
            if data[p] != 0xFF:
                p += 1
                continue
            marker = data[p + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
                p += 1 if marker == 0xFF else 2
                continue
            (length,) = struct.unpack(">H", data[p + 2 : p + 4])
            if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
                h, w = struct.unpack(">HH", data[p + 5 : p + 9])
                return int(w), int(h)
            p += 2 + length
        raise ValueError("JPEG image: no frame header found")
    raise ValueError("encoded image: only PNG and JPEG are accepted (or pass a numpy array)")


def image_message(image: ImageInput, bgr: bool = False) -> Tuple[pb.Image, int, int]:
    """The Image message and the image's (width, height).

    numpy arrays are sent raw (HxWx3 uint8 RGB; ``bgr=True`` for OpenCV frames; HxW grey
    and HxWx4 with alpha are accepted); bytes and paths are sent encoded (PNG/JPEG)."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        w, h = encoded_size(data)
        return pb.Image(encoded=data), w, h
    if _is_path(image):
        data = Path(image).read_bytes()  # type: ignore[arg-type]
        w, h = encoded_size(data)
        return pb.Image(encoded=data), w, h
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise ValueError(f"image: expected uint8 pixels, got {a.dtype} (scale floats to 0-255 and convert)")
    if a.ndim == 2:
        a = np.stack([a, a, a], axis=-1)
    elif a.ndim == 3 and a.shape[2] == 4:
        a = a[:, :, :3]
    elif not (a.ndim == 3 and a.shape[2] == 3):
        raise ValueError(f"image: expected HxWx3 (or HxW, HxWx4), got shape {a.shape}")
    if bgr:
        a = a[:, :, ::-1]
    h, w = a.shape[:2]
    return pb.Image(raw_rgb8=np.ascontiguousarray(a).tobytes(), width=w, height=h), int(w), int(h)


DepthInput = Union[npt.ArrayLike, bytes, str, "os.PathLike[str]"]


def depth_message(depth: DepthInput, depth_scale: Optional[float], width: int, height: int) -> pb.Depth:
    """The Depth message for a depth image registered to the colour image (``width`` x
    ``height``), 0 = no measurement.

    numpy HxW uint16 (OpenCV's ``IMREAD_ANYDEPTH``, pyrealsense2's z16, Kinect) is sent raw
    with ``depth_scale`` millimetres per unit (1 for millimetres, 0.1 for tenths: BOP's
    ``depth_scale``; a RealSense's depth unit in metres times 1000); float arrays are metres
    (Open3D, pyrealsense2 after scaling) and take no scale. Bytes and paths are a 16-bit PNG
    with ``depth_scale``."""
    if isinstance(depth, (bytes, bytearray, memoryview)) or _is_path(depth):
        data = bytes(depth) if isinstance(depth, (bytes, bytearray, memoryview)) else Path(depth).read_bytes()  # type: ignore[arg-type]
        return pb.Depth(png16=data, scale_mm=_depth_scale(depth_scale, "a 16-bit PNG"))
    a = np.asarray(depth)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim != 2:
        raise ValueError(f"depth: expected an HxW array, got shape {a.shape}")
    if a.shape != (height, width):
        raise ValueError(f"depth is {a.shape[1]}x{a.shape[0]} but the image is {width}x{height}: it must be registered to the colour image")
    if a.dtype == np.uint16:
        raw = np.ascontiguousarray(a, dtype="<u2").tobytes()
        return pb.Depth(raw_u16=raw, width=width, height=height, scale_mm=_depth_scale(depth_scale, "uint16 depth"))
    if np.issubdtype(a.dtype, np.floating):
        if depth_scale is not None:
            raise ValueError("depth_scale is for uint16 depth and PNGs: float depth is metres")
        return pb.Depth(raw_f32=np.ascontiguousarray(a, dtype="<f4").tobytes(), width=width, height=height)
    raise ValueError(f"depth: expected uint16 (with depth_scale) or float metres, got {a.dtype}")


def _depth_scale(scale: Optional[float], what: str) -> float:
    if scale is None:
        raise ValueError(f"depth_scale is needed with {what}: millimetres per unit (1 for millimetres, 0.1 for tenths)")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"depth_scale must be a finite positive number of millimetres per unit, not {scale!r}")
    return float(scale)


def intrinsics_message(K: IntrinsicsInput, width: int, height: int) -> pb.Intrinsics:
    """K as a 3x3 matrix or (fx, fy, cx, cy), with the image's size."""
    a = np.asarray(K, dtype=np.float64)
    if a.shape == (3, 3):
        fx, fy, cx, cy = a[0, 0], a[1, 1], a[0, 2], a[1, 2]
        if a[0, 1] != 0 or a[1, 0] != 0 or a[2, 0] != 0 or a[2, 1] != 0 or a[2, 2] != 1:
            raise ValueError(f"K must be a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]], got {a.tolist()}")
    elif a.shape == (4,):
        fx, fy, cx, cy = a
    elif a.shape == (9,):
        return intrinsics_message(a.reshape(3, 3), width, height)
    else:
        raise ValueError(f"K: expected a 3x3 matrix or (fx, fy, cx, cy), got shape {a.shape}")
    return pb.Intrinsics(fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=width, height=height)


def K_matrix(K: IntrinsicsInput) -> npt.NDArray[np.float64]:
    """K as a 3x3 float64 matrix, from either form."""
    a = np.asarray(K, dtype=np.float64)
    if a.shape == (3, 3):
        return a
    if a.shape == (9,):
        return a.reshape(3, 3)
    if a.shape == (4,):
        fx, fy, cx, cy = a
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    raise ValueError(f"K: expected a 3x3 matrix or (fx, fy, cx, cy), got shape {a.shape}")


# ------------------------------------------------------------------------ detections


def _rle_message(counts: Sequence[int], h: int, w: int) -> pb.Rle:
    return pb.Rle(counts=list(counts), height=h, width=w)


def detection_message(d: DetectionInput, width: int, height: int) -> pb.Detection:
    det = as_detection(d)
    m = pb.Detection(object_id=det.object_id)
    if det.mask is not None:
        if isinstance(det.mask, (bytes, bytearray, memoryview)):
            m.mask_png = bytes(det.mask)
        elif _is_path(det.mask):
            m.mask_png = Path(det.mask).read_bytes()  # type: ignore[arg-type]
        else:
            a = np.asarray(det.mask)
            if a.ndim == 3 and a.shape[2] in (1, 3, 4):
                a = a.max(axis=2)  # a colour / single-channel PNG read by OpenCV
            if a.shape != (height, width):
                raise ValueError(f"detection of {det.object_id!r}: mask is {a.shape[:2]}, the image is ({height}, {width})")
            m.mask_rle.CopyFrom(_rle_message(*_masks.mask_to_counts(a)))
    elif det.rle is not None:
        m.mask_rle.CopyFrom(_rle_message(*_masks.rle_counts(det.rle)))
    if det.box is not None:
        box = [float(v) for v in det.box]
        if len(box) != 4:
            raise ValueError(f"detection of {det.object_id!r}: box must be (x, y, width, height), got {det.box!r}")
        m.bbox.CopyFrom(pb.BBox(x=box[0], y=box[1], width=box[2], height=box[3]))
    if det.score is not None:
        m.score = float(det.score)
    return m
