#!/usr/bin/env python3
"""Exports a DINOv3 (or DINOv2-with-registers) ViT to the ONNX backbone b2tfpose runs.

Runs on the user's machine, where the licence-gated weights are: from a local checkpoint
folder (or a Hugging Face model id that is already in the local cache) to one ONNX file
with a fixed [batch, 3, S, S] input (S = 32 × patch size; dynamic batch) and two outputs
of patch tokens only (class and register tokens dropped): `local_tokens`, the output of
block `--local-layer`, and `global_tokens`, the last block after the final norm; plus
the JSON sidecar b2tfpose checks (docs/onnx_backbone.md). The ONNX model is compared
with PyTorch on one input and nothing is written when they disagree.

    python3 tools/export_backbone.py --model PATH_OR_ID --out models/dinov3-vitl16.onnx
        [--local-layer N] [--fp16] [--fused-attention] [--size S] [--opset 18]
    python3 tools/export_backbone.py --random-init dinov3-tiny --out /tmp/t.onnx   # tests

Default local layer: 18 for a 24-block ViT-L (the paper), else three quarters of the
depth. `--fused-attention` writes each block's attention as ONNX Runtime's
`com.microsoft.MultiHeadAttention` (rotary positions applied before it), which its CUDA
provider runs as one fused kernel; the plain export spells attention out as
MatMul/Softmax/MatMul, which ONNX Runtime's optimizer cannot fuse around DINOv3's rotary
positions. Needs torch, transformers (≥ 4.56 for DINOv3), onnx and onnxruntime.
"""

import argparse
import hashlib
import json
import os
import sys
import tempfile

import numpy as np

IMAGENET_MEAN = [0.485, 0.456, 0.406]
IMAGENET_STD = [0.229, 0.224, 0.225]
GRID = 32  # patches per side of a crop, as the embedded backbone's (512 px at patch 16)


def random_model(kind):
    """A small randomly initialised ViT of the real architecture (no weights needed)."""
    # DINOv3's published shapes (width, depth, heads); random weights run as fast as real ones,
    # so these time a GPU without the licence-gated checkpoints.
    dinov3_shapes = {"dinov3-tiny": (64, 4, 2), "dinov3-vits16": (384, 12, 6), "dinov3-vitb16": (768, 12, 12), "dinov3-vitl16": (1024, 24, 16)}
    if kind in dinov3_shapes:
        from transformers import DINOv3ViTConfig, DINOv3ViTModel

        width, depth, heads = dinov3_shapes[kind]
        cfg = DINOv3ViTConfig(
            hidden_size=width, intermediate_size=(2 if kind == "dinov3-tiny" else 4) * width, num_hidden_layers=depth, num_attention_heads=heads, patch_size=16, image_size=512, num_register_tokens=4
        )
        return DINOv3ViTModel(cfg).eval(), f"random-init {kind}"
    if kind == "dinov2reg-tiny":
        from transformers import Dinov2WithRegistersConfig, Dinov2WithRegistersModel

        cfg = Dinov2WithRegistersConfig(hidden_size=64, intermediate_size=128, num_hidden_layers=4, num_attention_heads=2, patch_size=14, image_size=448, num_register_tokens=4)
        return Dinov2WithRegistersModel(cfg).eval(), f"random-init {kind}"
    sys.exit(f"unknown --random-init {kind!r}: {', '.join([*dinov3_shapes, 'dinov2reg-tiny'])}")


def load_model(name):
    from transformers import AutoModel

    try:
        model = AutoModel.from_pretrained(name, local_files_only=not os.path.isdir(name) and os.environ.get("HF_HUB_OFFLINE") == "1")
    except Exception as e:  # noqa: BLE001 - the message is what the user needs
        sys.exit(f"cannot load {name!r}: {e}\n(DINOv3 is licence-gated: accept the licence on its model page, download it, and pass the folder)")
    return model.eval(), name


def normalisation(name):
    """Mean and std from the checkpoint's image processor, else ImageNet's."""
    try:
        from transformers import AutoImageProcessor

        p = AutoImageProcessor.from_pretrained(name)
        return [float(x) for x in p.image_mean], [float(x) for x in p.image_std]
    except Exception:  # noqa: BLE001 - no processor config: the ViTs' shared default
        return IMAGENET_MEAN, IMAGENET_STD


def freeze_position_embeddings(model, size, patch, dim):
    """DINOv2's learned position embeddings are resized to the input on every call, with an
    antialiased bicubic that ONNX lacks (and that traces even when the size already
    matches). The export has one input size: resize once here, in PyTorch, and let the
    graph hold the result as a constant. (DINOv3's rotary positions need nothing.)"""
    import torch

    emb = getattr(model, "embeddings", None)
    if emb is None or not hasattr(emb, "interpolate_pos_encoding"):
        return
    with torch.no_grad():
        fixed = emb.interpolate_pos_encoding(torch.zeros(1, 1 + (size // patch) ** 2, dim), size, size).detach()
    emb.interpolate_pos_encoding = lambda embeddings, height, width: fixed.to(embeddings.dtype)


def use_fused_attention(model):
    """Routes the model's attention through `com.microsoft.MultiHeadAttention` in the export.

    transformers' ViTs call a pluggable attention function with query, key and value as
    [batch, heads, tokens, head_dim] (DINOv3's rotary positions already applied); this one
    computes the same attention in PyTorch (the reference the export is checked against)
    and exports as the single contrib op, which takes [batch, tokens, heads × head_dim]."""
    import torch
    from transformers import AttentionInterface

    # A custom op, so the tracer records it as one node and the symbolic below writes it.
    @torch.library.custom_op("b2tf::multi_head_attention", mutates_args=())
    def multi_head_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, num_heads: int, scale: float) -> torch.Tensor:
        b, s, _ = q.shape
        split = lambda t: t.view(b, s, num_heads, -1).transpose(1, 2)  # noqa: E731
        out = torch.nn.functional.scaled_dot_product_attention(split(q), split(k), split(v), scale=scale)
        return out.transpose(1, 2).reshape(b, s, -1)

    def symbolic(g, q, k, v, num_heads, scale):
        from torch.onnx import symbolic_helper

        heads = symbolic_helper._get_const(num_heads, "i", "num_heads")
        factor = symbolic_helper._get_const(scale, "f", "scale")
        out = g.op("com.microsoft::MultiHeadAttention", q, k, v, num_heads_i=heads, scale_f=factor)
        out.setType(q.type())  # same shape and type as the query: tells the exporter's shape inference
        return out

    torch.onnx.register_custom_op_symbolic("b2tf::multi_head_attention", symbolic, 1)

    def attention(module, query, key, value, attention_mask, scaling=None, dropout=0.0, **kwargs):
        if attention_mask is not None:
            raise ValueError("--fused-attention: this model passes an attention mask, which the export does not carry")
        b, heads, tokens, head_dim = query.shape
        scale = float(scaling if scaling is not None else head_dim**-0.5)
        merge = lambda t: t.transpose(1, 2).reshape(b, tokens, heads * head_dim)  # noqa: E731
        out = multi_head_attention(merge(query), merge(key), merge(value), heads, scale)
        return out.view(b, tokens, heads, head_dim), None

    AttentionInterface.register("b2tf_mha", attention)
    model.set_attn_implementation("b2tf_mha")


class PatchTokens:
    """Wraps the ViT: pixels in, (local block's patch tokens, final-norm patch tokens) out."""

    def __init__(self, model, local_layer, half):
        import torch

        class Wrapper(torch.nn.Module):
            def __init__(self):
                super().__init__()
                self.model = model
                self.prefix = 1 + int(getattr(model.config, "num_register_tokens", 0))

            def forward(self, pixel_values):
                x = pixel_values.half() if half else pixel_values
                out = self.model(pixel_values=x, output_hidden_states=True)
                local = out.hidden_states[local_layer][:, self.prefix :, :]
                final = out.last_hidden_state[:, self.prefix :, :]
                return local.float(), final.float()

        self.module = Wrapper().eval()
        if half:
            self.module.half()


def export(args):
    import onnx
    import onnxruntime as ort
    import torch

    if args.random_init:
        model, source = random_model(args.random_init)
        mean, std = IMAGENET_MEAN, IMAGENET_STD
        name = args.random_init
    else:
        model, source = load_model(args.model)
        mean, std = normalisation(args.model)
        name = os.path.basename(os.path.normpath(args.model))
    cfg = model.config
    depth = int(cfg.num_hidden_layers)
    patch = int(cfg.patch_size)
    dim = int(cfg.hidden_size)
    local_layer = args.local_layer or (18 if depth == 24 else max(1, round(0.75 * depth)))
    if not 1 <= local_layer <= depth:
        sys.exit(f"--local-layer {local_layer} is outside 1–{depth}")
    size = args.size or GRID * patch
    if size % patch:
        sys.exit(f"--size {size} is not a multiple of the patch size {patch}")
    freeze_position_embeddings(model, size, patch, dim)
    if args.fused_attention:
        use_fused_attention(model)
    wrapped = PatchTokens(model, local_layer, args.fp16).module
    example = torch.randn(2, 3, size, size, generator=torch.Generator().manual_seed(0))
    # Tracing and the reference pass run on a GPU where there is one (a ViT-L in fp16 crawls on
    # most CPUs); the graph does not depend on where it was traced. TF32 off: the reference
    # must be full float32 to be compared within 1e-3.
    device = "cuda" if torch.cuda.is_available() else "cpu"
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    wrapped = wrapped.to(device)
    out_dir = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(out_dir, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
        path = os.path.join(tmp, "model.onnx")
        with torch.no_grad():
            torch.onnx.export(
                wrapped,
                (example.to(device),),
                path,
                input_names=["pixel_values"],
                output_names=["local_tokens", "global_tokens"],
                dynamic_axes={"pixel_values": {0: "batch"}, "local_tokens": {0: "batch"}, "global_tokens": {0: "batch"}},
                opset_version=args.opset,
                custom_opsets={"com.microsoft": 1} if args.fused_attention else None,
                dynamo=False,
            )
            ref_local, ref_global = (t.cpu().numpy() for t in wrapped(example.to(device)))
        # Weights of large models may land in a side file: fold everything into one file.
        m = onnx.load(path, load_external_data=True)
        data = m.SerializeToString() if m.ByteSize() < 2**31 - 1 else None
        if data is None:
            sys.exit("the model is over 2 GB: ONNX's single-file limit (export with --fp16)")
        sess = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
        got_local, got_global = sess.run(["local_tokens", "global_tokens"], {"pixel_values": example.numpy()})
        tol = args.tolerance if args.tolerance is not None else (5e-2 if args.fp16 else 1e-3)
        for label, ref, got in (("local", ref_local, got_local), ("global", ref_global, got_global)):
            err = float(np.max(np.abs(ref - got)))
            scale = float(np.max(np.abs(ref))) or 1.0
            print(f"{label} tokens {list(got.shape)}: largest |ONNX − PyTorch| {err:.2e} (values up to {scale:.2f})")
            if got.shape != ref.shape or not err <= tol * max(scale, 1.0):
                sys.exit(f"ONNX output {label} disagrees with PyTorch ({err:.3e} > {tol * max(scale, 1.0):.3e}): nothing written")
        sidecar = {
            "format": "b2tfpose-backbone",
            "version": 1,
            "model": f"{name}{'-fp16' if args.fp16 else ''}{'-mha' if args.fused_attention else ''}",
            "source": source,
            "patch_size": patch,
            "input_size": size,
            "mean": mean,
            "std": std,
            "input": "pixel_values",
            "local_output": "local_tokens",
            "global_output": "global_tokens",
            "depth": depth,
            "local_layer": local_layer,
            "global_layer": depth,
            "local_dim": dim,
            "global_dim": dim,
            "dtype": "float32",
            "onnx_sha256": hashlib.sha256(data).hexdigest(),
        }
    with open(args.out, "wb") as f:
        f.write(data)
    with open(os.path.splitext(args.out)[0] + ".json", "w") as f:
        json.dump(sidecar, f, indent=2)
    print(f"wrote {args.out} ({len(data) / 1e6:.1f} MB) and its .json: {depth} blocks, local block {local_layer}, dim {dim}, {size}² input")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", help="checkpoint folder (or a model id in the local Hugging Face cache)")
    src.add_argument("--random-init", help="dinov3-tiny or dinov2reg-tiny (small random models, for tests), or dinov3-vits16/-vitb16/-vitl16 (random weights in DINOv3's shapes, for timing)")
    p.add_argument("--out", required=True, help="the .onnx file to write (its .json beside it)")
    p.add_argument("--local-layer", type=int, help="block giving the local descriptors (default: 18 of 24, else 3/4 of the depth)")
    p.add_argument("--size", type=int, help="input side in pixels (default: 32 patches)")
    p.add_argument("--fp16", action="store_true", help="half-precision weights and activations (inputs and outputs stay float32)")
    p.add_argument("--fused-attention", action="store_true", help="attention as ONNX Runtime's fused com.microsoft.MultiHeadAttention op (faster on its CUDA provider)")
    p.add_argument("--opset", type=int, default=18)
    p.add_argument("--tolerance", type=float, help="largest |ONNX − PyTorch| accepted, relative to the outputs' largest value (default: 1e-3, with --fp16 5e-2)")
    export(p.parse_args())


if __name__ == "__main__":
    main()
