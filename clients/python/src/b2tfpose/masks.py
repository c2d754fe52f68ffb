"""Masks as run-length encodings: BOP / COCO uncompressed (``{"counts": [..], "size":
[h, w]}``) and COCO's compressed string counts, to and from numpy, with no pycocotools.

Runs are column-major (Fortran order), the first run is background, as in COCO and as
the service's ``Rle`` message expects.
"""

from __future__ import annotations

from typing import Any, Dict, List, Mapping, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

RleDict = Dict[str, Any]


def mask_to_counts(mask: npt.ArrayLike) -> Tuple[List[int], int, int]:
    """Column-major run lengths of a 2-D mask (non-zero = object), first run background:
    (counts, height, width)."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"a mask must be 2-D (height x width), got shape {m.shape}")
    h, w = m.shape
    flat = (m != 0).flatten(order="F").astype(np.int8)
    if flat.size == 0:
        return [0], h, w
    change = np.flatnonzero(np.diff(flat)) + 1
    bounds = np.concatenate(([0], change, [flat.size]))
    counts = np.diff(bounds).tolist()
    if flat[0] == 1:
        counts = [0] + counts
    return [int(c) for c in counts], int(h), int(w)


def mask_to_rle(mask: npt.ArrayLike) -> RleDict:
    """COCO uncompressed RLE dict of a mask."""
    counts, h, w = mask_to_counts(mask)
    return {"counts": counts, "size": [h, w]}


def counts_to_mask(counts: Sequence[int], height: int, width: int) -> npt.NDArray[np.bool_]:
    """The boolean mask of column-major run lengths (first run background)."""
    total = int(sum(counts))
    if total != height * width:
        raise ValueError(f"RLE counts sum to {total}, not height * width = {height * width}")
    values = np.zeros(len(counts), dtype=bool)
    values[1::2] = True
    flat = np.repeat(values, np.asarray(counts, dtype=np.int64))
    return flat.reshape((height, width), order="F")


def decode_compressed_counts(s: Union[str, bytes]) -> List[int]:
    """COCO's compressed counts string (pycocotools' ``rleFrString``) to run lengths."""
    data = s.encode("ascii") if isinstance(s, str) else s
    counts: List[int] = []
    p = 0
    while p < len(data):
        x = 0
        k = 0
        more = True
        while more:
            c = data[p] - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def encode_compressed_counts(counts: Sequence[int]) -> str:
    """Run lengths to COCO's compressed counts string (pycocotools' ``rleToString``)."""
    out = bytearray()
    for i, c in enumerate(counts):
        x = int(c)
        if i > 2:
            x -= int(counts[i - 2])
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(ch + 48)
    return out.decode("ascii")


def rle_counts(rle: Mapping[str, Any]) -> Tuple[List[int], int, int]:
    """(counts, height, width) of a COCO RLE dict, compressed or not."""
    try:
        size = rle["size"]
        counts = rle["counts"]
    except KeyError as e:
        raise ValueError(f"an RLE dict needs 'counts' and 'size' ([height, width]); missing {e}") from None
    h, w = int(size[0]), int(size[1])
    if isinstance(counts, (str, bytes)):
        return decode_compressed_counts(counts), h, w
    return [int(c) for c in counts], h, w


def rle_to_mask(rle: Mapping[str, Any]) -> npt.NDArray[np.bool_]:
    """The boolean mask of a COCO RLE dict (compressed or not)."""
    counts, h, w = rle_counts(rle)
    return counts_to_mask(counts, h, w)


def compress_rle(rle: Mapping[str, Any]) -> RleDict:
    """The same RLE with COCO's compressed string counts."""
    counts, h, w = rle_counts(rle)
    return {"counts": encode_compressed_counts(counts), "size": [h, w]}
