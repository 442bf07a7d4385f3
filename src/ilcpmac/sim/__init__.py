"""The numba motor simulator and its validating Python wrapper."""
