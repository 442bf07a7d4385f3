"""The core: what every layer shares and that imports nothing else of the package.

The records that cross every boundary (`records`), the current loop's model (`current_loop`), records of
count means over encoder lines (`binning`), the torque sensor's response (`torque_sensor`), what measures the
torque (`torque_source`), the errors (`errors`), the schema kit every config and file format is declared with
(`schema`), bounded reading and atomic writing of files (`files`), plugin discovery (`plugins`), process
settings (`runtime`) and the seed of each trial (`seeds`).
"""

# The package imports none of its modules: `ilcpmac.cli` imports `ilcpmac.core.errors` and
# `ilcpmac.core.runtime` before numpy, whose thread count `ilcpmac.core.runtime.tune_process` sets first.
__all__: list[str] = []
