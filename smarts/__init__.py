"""A fast, PyTorch-native driving simulator and RL framework."""

__version__ = "0.1.0"
