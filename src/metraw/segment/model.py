"""Compact U-Net for car segmentation on packed, variance-stabilised raw planes (plain torch).

Input: (B, S, h, w) packed CFA planes in VST units (unit noise variance, see
``metraw.segment.data``), S = 4 for Bayer (canonical R, G, G, B site order), 1 for mono.
Output: (B, 1, h, w) logits of "car" on the same (packed, native) grid.

``Segmenter`` optionally upsamples the input bilinearly by an integer ``upsample`` factor before
the U-Net and average-pools the logits back, so the loss and the IoU always live on the image's
own packed grid; this lets coarse (satellite) images use the same receptive field in pixels as
a larger image (compare the choices in ``benchmarks/segment.py``).
"""

from __future__ import annotations

import torch
from torch import nn
import torch.nn.functional as F


def _norm(channels: int) -> nn.Module:
    # GroupNorm: independent of batch composition (padding, batch size), same in train and eval.
    return nn.GroupNorm(min(8, channels), channels)


class _Block(nn.Sequential):
    def __init__(self, cin: int, cout: int):
        super().__init__(
            nn.Conv2d(cin, cout, 3, padding=1, bias=False), _norm(cout), nn.ReLU(inplace=True),
            nn.Conv2d(cout, cout, 3, padding=1, bias=False), _norm(cout), nn.ReLU(inplace=True),
        )


class UNet(nn.Module):
    """U-Net with ``depth`` poolings and ``base_channels`` * 2**level channels per level."""

    def __init__(self, in_channels: int, base_channels: int = 16, depth: int = 3):
        super().__init__()
        self.depth = depth
        chans = [base_channels * 2**i for i in range(depth + 1)]
        self.down = nn.ModuleList()
        cin = in_channels
        for c in chans[:-1]:
            self.down.append(_Block(cin, c))
            cin = c
        self.bottom = _Block(chans[-2], chans[-1])
        self.up = nn.ModuleList()
        self.dec = nn.ModuleList()
        for i in range(depth - 1, -1, -1):
            self.up.append(nn.ConvTranspose2d(chans[i + 1], chans[i], 2, stride=2))
            self.dec.append(_Block(2 * chans[i], chans[i]))
        self.head = nn.Conv2d(chans[0], 1, 1)

    @property
    def multiple(self) -> int:
        """Input sides must be multiples of this (2**depth)."""
        return 2**self.depth

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottom(x)
        for up, dec in zip(self.up, self.dec):
            x = up(x)
            x = dec(torch.cat([x, skips.pop()], dim=1))
        return self.head(x)


class Segmenter(nn.Module):
    """U-Net wrapped with optional bilinear input upsampling and padding to a valid size.

    ``forward(x)`` accepts any (B, S, h, w) and returns logits (B, 1, h, w) on the input grid.
    """

    def __init__(self, in_channels: int, base_channels: int = 16, depth: int = 3, upsample: int = 1):
        super().__init__()
        if upsample < 1:
            raise ValueError("upsample must be an integer >= 1")
        self.upsample = int(upsample)
        self.unet = UNet(in_channels, base_channels, depth)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        f = self.upsample
        if f > 1:
            x = F.interpolate(x, scale_factor=f, mode="bilinear", align_corners=False)
        m = self.unet.multiple
        ph, pw = (-x.shape[-2]) % m, (-x.shape[-1]) % m
        if ph or pw:
            mode = "reflect" if min(x.shape[-2:]) > max(ph, pw) else "replicate"
            x = F.pad(x, (0, pw, 0, ph), mode=mode)
        y = self.unet(x)[..., : h * f, : w * f]
        if f > 1:
            y = F.avg_pool2d(y, f)
        return y
