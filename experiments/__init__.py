"""Hydra entry points of somtorch (thin: compose → build → run → write)."""
