"""The physics a raw image passes through: diffraction and geometric kernels (``optics``), the atmosphere
(``atmosphere``), the daylight spectrum (``daylight``), where photons land (``photon_landing``), the Fourier
gridding of the emulator (``gridding``), accuracy targets (``accuracy``) and the raw functions that apply them to
pixels while keeping each pixel's error known (``rawfunc``)."""
