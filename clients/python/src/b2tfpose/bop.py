"""BOP results CSV (https://bop.felk.cvut.cz/challenges/): one row per estimated pose,
``scene_id,im_id,obj_id,score,R,t,time`` with R's 9 values row-major and t's 3 values in
millimetres, space-separated; time is the image's run time in seconds (-1: unknown)."""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from typing import IO, Iterable, List, Optional, Union

import numpy as np

from ._pose import Pose
from ._types import Result

HEADER = "scene_id,im_id,obj_id,score,R,t,time"


@dataclass(frozen=True)
class BopRow:
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    pose: Pose
    time: float = -1.0

    def line(self) -> str:
        """The CSV line (no newline)."""
        R = " ".join(repr(float(v)) for v in self.pose.R.reshape(-1))
        t = " ".join(repr(float(v)) for v in self.pose.t_mm)
        return f"{self.scene_id},{self.im_id},{self.obj_id},{float(self.score)!r},{R},{t},{float(self.time)!r}"


def row(scene_id: int, im_id: int, obj_id: int, result: Union[Result, Pose], score: Optional[float] = None, time: float = -1.0) -> BopRow:
    """A row from a :class:`~b2tfpose.Result` (its pose and score) or a :class:`Pose`
    (``score`` then defaults to 1). ``time``: seconds spent on the image."""
    if isinstance(result, Result):
        if result.pose is None:
            raise ValueError(f"BOP row of object {obj_id}: the result has no pose ({result.reason})")
        return BopRow(scene_id, im_id, obj_id, result.score if score is None else score, result.pose, time)
    return BopRow(scene_id, im_id, obj_id, 1.0 if score is None else score, result, time)


def format_rows(rows: Iterable[BopRow], header: bool = True) -> str:
    lines = ([HEADER] if header else []) + [r.line() for r in rows]
    return "\n".join(lines) + "\n"


def write_csv(path_or_file: Union[str, "os.PathLike[str]", IO[str]], rows: Iterable[BopRow], append: bool = False) -> None:
    """Writes (or appends, without a second header) BOP rows."""
    if isinstance(path_or_file, (str, os.PathLike)):
        exists = os.path.exists(path_or_file) and os.path.getsize(path_or_file) > 0
        with open(path_or_file, "a" if append else "w", newline="") as f:
            f.write(format_rows(rows, header=not (append and exists)))
    else:
        path_or_file.write(format_rows(rows, header=not append))


def read_csv(path_or_file: Union[str, "os.PathLike[str]", IO[str]]) -> List[BopRow]:
    """Parses a BOP results CSV (t back to metres in the poses)."""
    if isinstance(path_or_file, (str, os.PathLike)):
        with open(path_or_file, newline="") as f:
            text = f.read()
    else:
        text = path_or_file.read()
    out: List[BopRow] = []
    for rec in csv.DictReader(io.StringIO(text)):
        R = np.array([float(v) for v in rec["R"].split()]).reshape(3, 3)
        t = np.array([float(v) for v in rec["t"].split()]) / 1000.0
        out.append(BopRow(int(rec["scene_id"]), int(rec["im_id"]), int(rec["obj_id"]), float(rec["score"]), Pose(R, t), float(rec["time"])))
    return out
