"""Backends run trials: the simulator, a remote bench target, or a recorded bench folder."""

from ilcpmac.backends.base import Backend, BenchDescription, BenchLimits

__all__ = ["Backend", "BenchDescription", "BenchLimits"]
