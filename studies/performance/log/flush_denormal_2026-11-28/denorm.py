"""Denormal entries of a checkpoint's float32 tensors, by part: ``python denorm.py RUN/checkpoints/ep001000.pt``."""

import sys

import torch


def walk(obj, path=""):
    if isinstance(obj, torch.Tensor):
        yield path, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from walk(v, f"{path}/{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from walk(v, f"{path}/{i}")


def main(path: str) -> None:
    tiny = torch.finfo(torch.float32).tiny
    parts: dict[str, list[int]] = {}
    for name, t in walk(torch.load(path, map_location="cpu", weights_only=False)):
        if t.dtype != torch.float32:
            continue
        counts = parts.setdefault("/".join(name.split("/")[:4]), [0, 0, 0])
        counts[0] += int(((t != 0) & (t.abs() < tiny)).sum())
        counts[1] += t.numel()
        counts[2] += int((t == 0).sum())
    for name, (denormal, n, zeros) in parts.items():
        if n > 100:
            print(f"{name:60s} denormal {denormal:7d} of {n:8d} ({100 * denormal / n:.2f}%)  zeros {zeros}")


if __name__ == "__main__":
    main(sys.argv[1])
