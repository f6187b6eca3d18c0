"""Shared by the tests of bring-your-own networks (test_networks, bad_inputs/test_models)."""

from __future__ import annotations

import functools


@functools.cache
def smp_available() -> bool:
    """Whether segmentation-models-pytorch imports here (the ``models`` extra, with a torchvision that fits the
    installed torch: PyPI's CUDA torchvision does not import beside a CPU torch; CI runs these tests in a venv of
    its own, .ci/run)."""
    try:
        import segmentation_models_pytorch  # noqa: F401
    except Exception:
        return False
    return True
