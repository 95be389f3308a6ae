"""The multilayer perceptron of the generators and discriminators of trajGAN (Eq. 13-15) and lcGAN (Eq. 16-17)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torch import nn


def mlp(sizes: Sequence[int], act: Callable[[], nn.Module]) -> nn.Sequential:
    """``Linear(sizes[0], sizes[1]), act(), ..., Linear(sizes[-2], sizes[-1])``: no activation after the last layer."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)
