#!/usr/bin/env python3
"""Times DINOv3-shaped ViTs in PyTorch on a GPU: the reference for what the ONNX backbone's
CUDA path should reach (docs/onnx_backbone.md, "On a GPU").

Random weights (speed does not depend on their values), 512² crops (32×32 patches, as
b2tfpose feeds the backbone), eager PyTorch with its fused attention, one row per shape,
precision and batch: milliseconds per crop and crops per second, the median of `--repeats`
timed passes after warm-up passes.

    python3 tools/time_vit_torch.py [--shapes dinov3-vits16,dinov3-vitl16] [--batches 1,8,32]
"""

import argparse
import statistics
import sys
import time

SHAPES = {"dinov3-vits16": (384, 12, 6), "dinov3-vitb16": (768, 12, 12), "dinov3-vitl16": (1024, 24, 16)}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shapes", default="dinov3-vits16,dinov3-vitb16,dinov3-vitl16")
    p.add_argument("--batches", default="1,8,32")
    p.add_argument("--precisions", default="fp32,tf32,fp16,bf16")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--size", type=int, default=512)
    args = p.parse_args()

    import torch
    from transformers import DINOv3ViTConfig, DINOv3ViTModel

    if not torch.cuda.is_available():
        sys.exit("no CUDA device: this script times the GPU")
    print(f"device: {torch.cuda.get_device_name(0)}, torch {torch.__version__}")
    print("| shape | precision | batch | ms per crop | crops/s |")
    print("|---|---|---:|---:|---:|")
    for shape in args.shapes.split(","):
        if shape not in SHAPES:
            sys.exit(f"unknown shape {shape!r}: {', '.join(SHAPES)}")
        width, depth, heads = SHAPES[shape]
        cfg = DINOv3ViTConfig(hidden_size=width, intermediate_size=4 * width, num_hidden_layers=depth, num_attention_heads=heads, patch_size=16, image_size=args.size, num_register_tokens=4)
        base = DINOv3ViTModel(cfg).eval().cuda()
        for precision in args.precisions.split(","):
            dtype = {"fp32": torch.float32, "tf32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}[precision]
            torch.backends.cuda.matmul.allow_tf32 = precision == "tf32"
            torch.backends.cudnn.allow_tf32 = precision == "tf32"
            model = base.to(dtype)
            for batch in (int(b) for b in args.batches.split(",")):
                x = torch.randn(batch, 3, args.size, args.size, device="cuda", dtype=dtype)
                times = []
                with torch.inference_mode():
                    for i in range(3 + args.repeats):
                        torch.cuda.synchronize()
                        t0 = time.perf_counter()
                        model(pixel_values=x, output_hidden_states=True)
                        torch.cuda.synchronize()
                        if i >= 3:
                            times.append(time.perf_counter() - t0)
                ms = 1000 * statistics.median(times) / batch
                print(f"| {shape} | {precision} | {batch} | {ms:.2f} | {1000 / ms:.0f} |", flush=True)
        del base, model
        torch.cuda.empty_cache()


if __name__ == "__main__":
    main()
