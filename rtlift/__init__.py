"""rtlift: a real-time hybrid Wiener–convolution lift model and observer for burst-actuated flow control."""

from rtlift.hybrid import HybridModel, HybridOutput
from rtlift.modelfile import load_model, save_model
from rtlift.observer import Observer as Observer

__all__ = ["HybridModel", "HybridOutput", "load_model", "save_model"]
