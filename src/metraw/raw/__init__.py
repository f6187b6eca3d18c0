"""The data model of a raw image: the calibration profile (``profile``), the colour filter array (``cfa``), the
image with its mask, flags and provenance (``image``), the sensor's exposure and readout (``sensor``) and the
variance-stabilising transform of the codec and the networks (``vst``)."""
