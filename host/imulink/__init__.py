"""imulink: hardware-in-the-loop companion for MEMS attitude-estimation firmware."""

__version__ = "0.1.0"
