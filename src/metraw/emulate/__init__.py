"""Drone-to-satellite emulation: the target system (``target``), the emulator of one raw image (``emulator``)
and fresh draws of a source scene at a target point (``draws``)."""
