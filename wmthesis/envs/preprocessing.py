"""Frame preprocessing as pure functions (thesis 4.2.4, 4.4.4).

World Models: crop the border that carries no information, resize to 64x64, keep RGB.
PlaNet: resize the whole frame to 64x64 and keep 5 bits per channel; the models see floats in
[-0.5, 0.5) made as in PlaNet's official ``preprocess`` (with uniform dequantisation noise when
training) and ``postprocess`` turns them back into bytes.

Frames are ``uint8`` arrays of shape (H, W, C); batches may carry any leading dimensions.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

# (top, bottom, left, right): frame[top:bottom, left:right] keeps the play area.
CROPS = {
    # The author's crop: the ring with its ropes, without score, clock and logo.
    "Boxing": (30, 183, 28, 131),
    # Both sidewalks and the ten lanes (the chicken starts on the bottom sidewalk and scores on
    # the top one); drops the score line, the black left margin and the Activision logo.
    "Freeway": (14, 196, 8, 160),
}


def crop_resize(frame: np.ndarray, crop: tuple[int, int, int, int] | None, size: int = 64) -> np.ndarray:
    """Crop `frame` (H, W, C) uint8 to ``frame[top:bottom, left:right]`` and resize it.

    ``crop=None`` keeps the whole frame. Resizing uses area interpolation (cv2.INTER_AREA),
    the right filter for shrinking. Returns (size, size, C) uint8.
    """
    if crop is not None:
        top, bottom, left, right = crop
        frame = frame[top:bottom, left:right]
    return cv2.resize(np.ascontiguousarray(frame), (size, size), interpolation=cv2.INTER_AREA)


def quantize(frame: np.ndarray, bits: int = 5) -> np.ndarray:
    """Keep the `bits` high bits of each uint8 value: ``(x >> (8 - bits)) << (8 - bits)``.

    Any shape; uint8 in, uint8 out. With ``bits=5`` every value is a multiple of 8.
    """
    _check_bits(bits)
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise TypeError(f"quantize expects uint8 frames, got {frame.dtype}")
    shift = 8 - bits
    return (frame >> shift) << shift


def to_float(frames: np.ndarray | torch.Tensor, bits: int = 8,
             noise: torch.Generator | None = None) -> torch.Tensor:
    """uint8 frames (any shape) -> float32 tensor in [-0.5, 0.5), same shape.

    As PlaNet's official ``preprocess``: ``floor(x / 2**(8-bits)) / 2**bits - 0.5``. With a
    `noise` generator, uniform dequantisation noise in [0, 1 / 2**bits) is added (training).
    The layout is kept; models that want (C, H, W) permute themselves.
    """
    _check_bits(bits)
    x = torch.as_tensor(frames)
    if x.dtype != torch.uint8:
        raise TypeError(f"to_float expects uint8 frames, got {x.dtype}")
    bins = 2 ** bits
    x = torch.div(x, 2 ** (8 - bits), rounding_mode="floor").to(torch.float32) / bins
    if noise is not None:
        x = x + torch.rand(x.shape, generator=noise, device=x.device) / bins
    return x - 0.5


def to_uint8(frames: torch.Tensor, bits: int = 8) -> torch.Tensor:
    """Float frames in [-0.5, 0.5) (any shape) -> uint8 tensor, as PlaNet's ``postprocess``.

    ``floor(2**bits * (x + 0.5)) * 2**(8-bits)``, clipped to [0, 255]. Exact inverse of
    :func:`to_float` without noise: ``to_uint8(to_float(quantize(x, b), b), b) == quantize(x, b)``.
    """
    _check_bits(bits)
    bins = 2 ** bits
    x = torch.floor(bins * (frames + 0.5)) * (256 // bins)
    return x.clamp(0, 255).to(torch.uint8)


def _check_bits(bits: int) -> None:
    if not 1 <= bits <= 8:
        raise ValueError(f"bits must be in 1..8, got {bits}")
