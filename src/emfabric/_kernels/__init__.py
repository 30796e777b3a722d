"""Numba kernels: arrays in, arrays written in place. Private; wrapped by the modules above."""
