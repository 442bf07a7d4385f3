"""Backends run trials: the simulator, a remote bench target, or any backend a plugin installs.

Every backend is found in the entry-point group ``ilcpmac.backends`` (see
`ilcpmac.backends.registry` and docs/writing-a-backend.md).
"""

from ilcpmac.backends.base import Backend, BenchDescription, BenchLimits

__all__ = ["Backend", "BenchDescription", "BenchLimits"]
