"""The core: what every layer shares and that imports nothing else of the package.

The records that cross every boundary (`records`), the current loop's model (`current_loop`), the errors
(`errors`), the schema kit every config and file format is declared with (`schema`), bounded reading and
atomic writing of files (`files`), plugin discovery (`plugins`) and process settings (`runtime`).
"""

from ilcpmac.core.errors import (
    BackendError,
    BenchFormatError,
    ConfigError,
    IdentificationError,
    IlcpmacError,
    SafetyError,
    SimulationError,
)
from ilcpmac.core.records import (
    BenchDescription,
    BenchLimits,
    IdentificationResult,
    MethodEstimates,
    MotorInfo,
    SensorCalibration,
    TrialData,
    TrialRequest,
)

__all__ = ["BackendError", "BenchDescription", "BenchFormatError", "BenchLimits", "ConfigError",
           "IdentificationError", "IdentificationResult", "IlcpmacError", "MethodEstimates", "MotorInfo",
           "SafetyError", "SensorCalibration", "SimulationError", "TrialData", "TrialRequest"]
