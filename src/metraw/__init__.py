"""metraw: metrologically correct raw images for data-centric machine learning.

Calibrated raw images (``RawImage`` + ``CalibrationProfile``) flow through raw functions
that keep each pixel's error independent, unbiased and of known distribution: ingest and
calibration, drone-to-satellite emulation, a noise-preserving codec, segmentation and
tolerance derivation.
"""

from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

__version__ = "0.1.0"
__all__ = ["CalibrationProfile", "MetrawError", "RawImage", "__version__"]
