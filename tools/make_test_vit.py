#!/usr/bin/env python3
"""Builds a small ViT-shaped ONNX backbone with random weights, and its sidecar JSON.

It has the interface of a DINOv3 export from tools/export_backbone.py (issue 12): one input
`pixel_values` [batch, 3, S, S] (float32, normalised with the sidecar's mean/std), and two
outputs holding patch tokens only (class and register tokens dropped):
`local_tokens` [batch, P, D] after block `local_layer`, and `global_tokens` [batch, P, D]
after the last block and the final LayerNorm. The tests use it to run the ONNX backbone
end to end on ONNX Runtime's CPU provider without any download; speed figures for a given
shape do not depend on the weight values.

    python3 tools/make_test_vit.py --out DIR [--dim 32 --depth 4 --heads 2 --size 512]
        [--reference]   # also write a fixed input and onnxruntime-python's outputs on it

Needs numpy and onnx (and onnxruntime for --reference).
"""

import argparse
import hashlib
import json
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

REGISTERS = 4  # DINOv3 has four register tokens besides the class token


class Graph:
    def __init__(self, rng):
        self.rng = rng
        self.nodes = []
        self.inits = []
        self.count = 0

    def name(self, base):
        self.count += 1
        return f"{base}_{self.count}"

    def const(self, base, array):
        n = self.name(base)
        self.inits.append(numpy_helper.from_array(np.asarray(array), n))
        return n

    def weight(self, base, shape, std=0.02):
        return self.const(base, (self.rng.standard_normal(shape) * std).astype(np.float32))

    def op(self, kind, inputs, base=None, **attrs):
        out = self.name(base or kind.lower())
        self.nodes.append(helper.make_node(kind, inputs, [out], **attrs))
        return out

    def layer_norm(self, x, dim):
        g = self.const("ln_g", (1.0 + self.rng.standard_normal(dim) * 0.1).astype(np.float32))
        b = self.const("ln_b", (self.rng.standard_normal(dim) * 0.05).astype(np.float32))
        return self.op("LayerNormalization", [x, g, b], axis=-1, epsilon=1e-6)

    def linear(self, x, d_in, d_out):
        y = self.op("MatMul", [x, self.weight("w", (d_in, d_out), std=d_in**-0.5)])
        return self.op("Add", [y, self.weight("b", (d_out,))])

    def heads(self, x, heads, dh):
        # [N, T, D] -> [N, H, T, dh]
        r = self.op("Reshape", [x, self.const("shape", np.array([0, -1, heads, dh], dtype=np.int64))])
        return self.op("Transpose", [r], perm=[0, 2, 1, 3])

    def block(self, x, dim, heads):
        dh = dim // heads
        h = self.layer_norm(x, dim)
        q, k, v = (self.heads(self.linear(h, dim, dim), heads, dh) for _ in range(3))
        kt = self.op("Transpose", [k], perm=[0, 1, 3, 2])
        scores = self.op("Mul", [self.op("MatMul", [q, kt]), self.const("scale", np.array(dh**-0.5, dtype=np.float32))])
        att = self.op("MatMul", [self.op("Softmax", [scores], axis=-1), v])
        merged = self.op("Reshape", [self.op("Transpose", [att], perm=[0, 2, 1, 3]), self.const("shape", np.array([0, -1, dim], dtype=np.int64))])
        x = self.op("Add", [x, self.linear(merged, dim, dim)])
        h = self.layer_norm(x, dim)
        u = self.linear(h, dim, 4 * dim)
        # GELU, exact: 0.5·u·(1 + erf(u/√2))
        erf = self.op("Erf", [self.op("Mul", [u, self.const("c", np.array(2**-0.5, dtype=np.float32))])])
        gelu = self.op("Mul", [self.op("Mul", [u, self.op("Add", [erf, self.const("one", np.array(1.0, dtype=np.float32))])]), self.const("half", np.array(0.5, dtype=np.float32))])
        return self.op("Add", [x, self.linear(gelu, 4 * dim, dim)])

    def patch_tokens(self, x, prefix):
        # Drop the class and register tokens: tokens [prefix:] along axis 1.
        return self.op("Slice", [x, self.const("start", np.array([prefix], dtype=np.int64)), self.const("end", np.array([2**62], dtype=np.int64)), self.const("axis", np.array([1], dtype=np.int64))])


def build(dim, depth, heads, size, patch, local_layer, seed):
    rng = np.random.default_rng(seed)
    g = Graph(rng)
    n = size // patch
    tokens = n * n
    prefix = 1 + REGISTERS
    conv = g.op(
        "Conv", ["pixel_values", g.weight("patch_w", (dim, 3, patch, patch), std=(3 * patch * patch) ** -0.5), g.weight("patch_b", (dim,))], kernel_shape=[patch, patch], strides=[patch, patch]
    )
    flat = g.op("Reshape", [conv, g.const("shape", np.array([0, dim, -1], dtype=np.int64))])
    patches = g.op("Transpose", [flat], perm=[0, 2, 1])
    # Class and register tokens, repeated over the batch.
    batch = g.op("Slice", [g.op("Shape", ["pixel_values"]), g.const("s", np.array([0], dtype=np.int64)), g.const("e", np.array([1], dtype=np.int64))])
    prefix_shape = g.op("Concat", [batch, g.const("rd", np.array([prefix, dim], dtype=np.int64))], axis=0)
    special = g.op("Expand", [g.weight("prefix_tokens", (1, prefix, dim), std=1.0), prefix_shape])
    x = g.op("Concat", [special, patches], axis=1)
    x = g.op("Add", [x, g.weight("pos", (1, prefix + tokens, dim), std=0.5)])
    local = None
    for layer in range(1, depth + 1):
        x = g.block(x, dim, heads)
        if layer == local_layer:
            local = g.patch_tokens(x, prefix)
    final = g.patch_tokens(g.layer_norm(x, dim), prefix)
    g.nodes.append(helper.make_node("Identity", [local], ["local_tokens"]))
    g.nodes.append(helper.make_node("Identity", [final], ["global_tokens"]))
    graph = helper.make_graph(
        g.nodes,
        "test_vit",
        [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, ["batch", 3, size, size])],
        [helper.make_tensor_value_info("local_tokens", TensorProto.FLOAT, ["batch", tokens, dim]), helper.make_tensor_value_info("global_tokens", TensorProto.FLOAT, ["batch", tokens, dim])],
        g.inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="b2tfpose tools/make_test_vit.py")
    model.ir_version = 8  # readable by every ONNX Runtime since 1.10
    onnx.checker.check_model(model)
    return model


def sidecar(args, onnx_bytes):
    return {
        "format": "b2tfpose-backbone",
        "version": 1,
        "model": f"test-vit-d{args.dim}-l{args.depth}",
        "source": f"random weights, tools/make_test_vit.py seed {args.seed}",
        "patch_size": args.patch,
        "input_size": args.size,
        "mean": [0.485, 0.456, 0.406],
        "std": [0.229, 0.224, 0.225],
        "input": "pixel_values",
        "local_output": "local_tokens",
        "global_output": "global_tokens",
        "depth": args.depth,
        "local_layer": args.local_layer,
        "global_layer": args.depth,
        "local_dim": args.dim,
        "global_dim": args.dim,
        "dtype": "float32",
        "onnx_sha256": hashlib.sha256(onnx_bytes).hexdigest(),
    }


def write_reference(out, onnx_path, size, seed):
    """A fixed input (two crops) and onnxruntime-python's outputs, raw little-endian f32."""
    import onnxruntime as ort

    rng = np.random.default_rng(seed + 1)
    x = rng.standard_normal((2, 3, size, size)).astype(np.float32)
    sess = ort.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
    local, glob = sess.run(["local_tokens", "global_tokens"], {"pixel_values": x})
    for name, a in (("input", x), ("local", local), ("global", glob)):
        a.astype("<f4").tofile(os.path.join(out, f"reference_{name}.f32"))
    with open(os.path.join(out, "reference.json"), "w") as f:
        json.dump({"input_shape": list(x.shape), "local_shape": list(local.shape), "global_shape": list(glob.shape), "onnxruntime": ort.__version__}, f)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for model.onnx and model.json")
    p.add_argument("--dim", type=int, default=32)
    p.add_argument("--depth", type=int, default=4)
    p.add_argument("--heads", type=int, default=2)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--patch", type=int, default=16)
    p.add_argument("--local-layer", type=int, default=None, help="default: three quarters of the depth")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--reference", action="store_true")
    args = p.parse_args()
    if args.local_layer is None:
        args.local_layer = max(1, round(0.75 * args.depth))
    if args.size % args.patch or args.dim % args.heads or not 1 <= args.local_layer <= args.depth:
        sys.exit("need size divisible by patch, dim by heads, and 1 ≤ local layer ≤ depth")
    os.makedirs(args.out, exist_ok=True)
    model = build(args.dim, args.depth, args.heads, args.size, args.patch, args.local_layer, args.seed)
    data = model.SerializeToString()
    onnx_path = os.path.join(args.out, "model.onnx")
    with open(onnx_path, "wb") as f:
        f.write(data)
    with open(os.path.join(args.out, "model.json"), "w") as f:
        json.dump(sidecar(args, data), f, indent=2)
    if args.reference:
        write_reference(args.out, onnx_path, args.size, args.seed)
    print(f"wrote {onnx_path} ({len(data) / 1e6:.1f} MB) and model.json")


if __name__ == "__main__":
    main()
