"""Streaming building blocks: each has step(), a batch twin simulate(), and explicit state."""

from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.lti import LTIBlock, spectral_radius, to_statespace
from rtlift.blocks.wiener import InputGain, OutputNonlinearity, WienerBlock

__all__ = ["RingConvolution", "HighPassFilter", "LTIBlock", "spectral_radius", "to_statespace",
           "InputGain", "OutputNonlinearity", "WienerBlock"]
