#!/usr/bin/env python3
"""How much each compact descriptor coding changes dense matching, on a stored object.

Codings are re-made here in numpy (as `b2tf onboard --descriptors` makes them, plus
variants not in the product) from an object's f16 patch descriptors. A proxy for
estimation: the patches of a few templates, as queries, are matched (mutual nearest
neighbours, k = 3, as `estimate::matching`) against the pooled patches of the 125
templates nearest by global descriptor (the template itself left out), once against the
exact rows and once against the coded ones. Printed per coding: the cosine of decoded to
exact rows, how many of the exact mutual matches survive (Jaccard of the two match sets),
and the share of matches whose template point lies within 0.05 / 0.1 diameters of the
query patch's own point (a right correspondence).

    .deps/pyclient-venv/bin/python3 tools/descriptor_codings.py out/bench-models/obj_000002 \
        f16 i8 pq4 pq2 opq4 pq4-long

Needs numpy (the Python client's venv has it). A few minutes per coding on 2 cores.
"""

import json
import struct
import sys

import numpy as np


def load(folder):
    with open(folder + "/tensors.safetensors", "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        header = json.loads(f.read(n))
        data = f.read()

    def tensor(name, dtype):
        a, b = header[name]["data_offsets"]
        return np.frombuffer(data[a:b], dtype=dtype).reshape(header[name]["shape"])

    if "patch_descriptors" not in header:
        sys.exit(f"{folder}: no f16 patch descriptors (stored with a compact coding)")
    if "patch_points" in header:
        points = tensor("patch_points", np.float32)
    else:  # format 7: grid steps
        grid = tensor("patch_point_grid", np.float32)
        points = grid[0] + tensor("patch_point_steps", np.uint16).astype(np.float32) * grid[1]
    manifest = json.load(open(folder + "/manifest.json"))
    ranges = [(t["patch_start"], t["patch_start"] + t["patch_count"]) for t in manifest["templates"]]
    return tensor("patch_descriptors", np.float16).astype(np.float32), points, tensor("global", np.float32), ranges, manifest["diameter_m"]


def unit(x):
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)


def nearest(x, c):
    out = np.empty(len(x), dtype=np.int64)
    for s in range(0, len(x), 65536):
        out[s : s + 65536] = (-2 * x[s : s + 65536] @ c.T + (c * c).sum(1)[None]).argmin(1)
    return out


def kmeans(x, k=256, iterations=12):
    """Lloyd from evenly strided rows, as src/onboard/pq.rs."""
    c = x[(np.arange(k) * len(x) // k) % len(x)].copy()
    for _ in range(iterations):
        a = nearest(x, c)
        counts = np.bincount(a, minlength=k)
        sums = np.zeros_like(c)
        np.add.at(sums, a, x)
        c[counts > 0] = sums[counts > 0] / counts[counts > 0, None]
    return c


def product_quantised(d, groups, fit_rows=32768, iterations=12):
    fit = d[:: max(1, len(d) // fit_rows)]
    out = np.empty_like(d)
    for g in groups:
        c = kmeans(fit[:, g].copy(), iterations=iterations)
        out[:, g] = c[nearest(d[:, g].copy(), c)]
    return out


def coded(name, d):
    dim = d.shape[1]
    slices = lambda m: [list(range(i * dim // m, (i + 1) * dim // m)) for i in range(m)]
    if name == "f16":
        return d
    if name == "i8":
        scale = np.abs(d).max(1, keepdims=True) / 127
        return np.round(d / scale) * scale
    if name == "pq4":
        return product_quantised(d, slices(dim // 4))
    if name == "pq2":
        return product_quantised(d, slices(dim // 2))
    if name == "pq4-long":  # 4× the training rows, twice the iterations
        return product_quantised(d, slices(dim // 4), fit_rows=131072, iterations=25)
    if name == "opq4":  # PCA rotation, components spread over subspaces by variance
        fit = d[:: max(1, len(d) // 32768)]
        w, v = np.linalg.eigh(np.cov(fit.T))
        order = np.argsort(-w)
        w, v = w[order], v[:, order]
        m, per = dim // 4, 4
        buckets, logs = [[] for _ in range(m)], np.zeros(m)
        for i in range(dim):
            b = min((b for b in range(m) if len(buckets[b]) < per), key=lambda b: logs[b])
            buckets[b].append(i)
            logs[b] += np.log(max(w[i], 1e-12))
        return product_quantised(d @ v, buckets) @ v.T
    sys.exit(f"unknown coding {name}")


def mutual(q, pool, k=3):
    s = q @ pool.T
    top = np.argpartition(-s, k, 1)[:, :k]
    best_query = s.argmax(0)
    keep = (best_query[top] == np.arange(len(q))[:, None]) & (np.take_along_axis(s, top, 1) > 0)
    return {(int(i), int(top[i, j])) for i, j in zip(*np.nonzero(keep))}


def main():
    folder, names = sys.argv[1], sys.argv[2:] or ["f16", "pq4"]
    d, points, glob, ranges, diameter = load(folder)
    exact = unit(d)
    rng = np.random.default_rng(0)
    trials = []
    for t in rng.choice(len(ranges), 12, replace=False):
        order = np.argsort(-(glob @ glob[t]))
        pool = np.concatenate([np.arange(*ranges[u]) for u in order if u != t][:125])
        q = exact[ranges[t][0] : ranges[t][1]]
        trials.append((q, points[ranges[t][0] : ranges[t][1]], pool, mutual(q, exact[pool])))
    print(f"{folder}: {len(d)} patches; 12 templates' patches against 125 templates each")
    print("| coding | cosine to exact, mean / 5th pct | exact mutual matches kept (Jaccard) | matches within 0.05·d / 0.1·d |")
    print("|---|---:|---:|---:|")
    for name in names:
        x = unit(coded(name, d))
        cos = (exact * x).sum(1)
        jaccard, errors = [], []
        for q, qp, pool, reference in trials:
            got = mutual(q, x[pool])
            jaccard.append(len(reference & got) / max(1, len(reference | got)))
            errors += [np.linalg.norm(qp[i] - points[pool[j]]) / diameter for i, j in got]
        errors = np.array(errors)
        print(f"| {name} | {cos.mean():.4f} / {np.percentile(cos, 5):.4f} | {np.mean(jaccard):.3f} | {np.mean(errors < 0.05):.3f} / {np.mean(errors < 0.1):.3f} |", flush=True)


if __name__ == "__main__":
    main()
