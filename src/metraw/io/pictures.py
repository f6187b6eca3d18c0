"""Picture files (PNG, JPEG, TIFF) decoded to arrays: the processed photos (`metraw.io.processed`) and the
label masks (`metraw.io.labels`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metraw.errors import MetrawError


def decode_image(path: Path) -> np.ndarray:
    """Decode PNG / JPEG / TIFF to an array (H, W[, C]); one clear error when the file is damaged."""
    import imagecodecs

    head = path.read_bytes()
    try:
        if head[:8] == b"\x89PNG\r\n\x1a\n":
            return imagecodecs.png_decode(head)
        if head[:3] == b"\xff\xd8\xff":
            return imagecodecs.jpeg8_decode(head)
        if head[:4] in (b"II*\x00", b"MM\x00*"):
            return imagecodecs.tiff_decode(head)
    except Exception as exc:  # imagecodecs raises codec-specific errors
        raise MetrawError(f"{path}: corrupt or truncated image ({exc})") from None
    raise MetrawError(f"{path}: unsupported image format (expected PNG, JPEG or TIFF)")
