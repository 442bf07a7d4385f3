"""Our schema kit (`ilcpmac.core.schema`) against pydantic v2, msgspec and cattrs, on two of our schemas.

The schemas: [limits] of a campaign config (`ilcpmac.config.LimitSettings`) and [motor] of bench.toml
(`ilcpmac.bench.format.MotorTable`), declared again in each library with the same types and ranges. For each
kit one run prints

- its import time, ms (``python -X importtime``, best of 5 fresh interpreters that have imported what
  ilcpmac imports anyway, numpy and tomllib): a library's modules and ours, `ilcpmac.core.schema` (which
  the package's `ilcpmac.core` imports first; the package's records are not the kit's cost);
- what it says of a wrong type, an out-of-range value and an unknown key in each table, cut to 60
  characters, and the number of lines it says it in (we need one line naming the file, the table and the
  key: a library names the key, the file and the table only with glue code of ours);
- the lines of code of the two declarations (docstrings and blank lines not counted), and of the kit.

A library that is not installed is skipped, saying so. Run: ``python benchmarks/schema_kits.py``.
"""

import importlib.util
import inspect
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Annotated, Callable

from ilcpmac.bench.format import MotorTable
from ilcpmac.config import LimitSettings
from ilcpmac.core.errors import ConfigError

#: what ilcpmac imports anyway, before any schema kit
BASELINE = "import numpy, tomllib"
#: the bad tables: table -> case -> the table's keys
CASES = {
    "limits": {"wrong type": {"max_current_a": "30"}, "out of range": {"max_current_a": -1.0},
               "unknown key": {"max_curent_a": 30.0}},
    "motor": {"wrong type": {"pole_pairs": 8.5}, "out of range": {"inertia": -0.01},
              "unknown key": {"slot": 48}},
}
#: the valid [motor] table the cases change
MOTOR = {"pole_pairs": 8, "slots": 48, "counts_per_rev": 4096, "inertia": 0.01056, "backemf_file": "backemf.csv"}


def _import_rows(statement: str) -> list[tuple[str, float]]:
    """(module, cumulative ms) of each module a fresh interpreter imports for ``BASELINE`` then ``statement``;
    a top-level import's module name has no indentation."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", f"{BASELINE}\n{statement}"],
                         capture_output=True, text=True, check=True).stderr
    rows = [line.removeprefix("import time:").split("|") for line in err.splitlines()
            if line.startswith("import time:") and "cumulative" not in line]
    return [(name.rstrip()[1:], 1e-3 * float(cumulative)) for _, cumulative, name in rows]


def import_ms(statement: str, module: str | None = None, repeats: int = 5) -> float:
    """The best of ``repeats`` import times of ``statement`` after `BASELINE`, ms: of ``module`` alone if given
    (its most indented row: where it was loaded, without its package), else of every top-level import the
    baseline has not."""
    baseline = {name for name, _ in _import_rows("") if not name.startswith(" ")}
    best = float("inf")
    for _ in range(repeats):
        rows = _import_rows(statement)
        if module is not None:
            ms = max((len(name) - len(name.lstrip()), t) for name, t in rows if name.strip() == module)[1]
        else:
            ms = sum(t for name, t in rows if not name.startswith(" ") and name not in baseline)
        best = min(best, ms)
    return best


def code_lines(*objects) -> int:
    """Lines of code of ``objects``' source: no blank lines, comments or docstrings."""
    lines = 0
    for obj in objects:
        source = textwrap.dedent(inspect.getsource(obj))
        doc = inspect.getdoc(obj) or ""
        lines += sum(1 for line in source.splitlines()
                     if line.strip() and not line.strip().startswith("#") and line.strip().strip('"') not in doc)
    return lines


# ---------------------------------------------------------------- the kits


def ours() -> tuple[str, Callable, tuple]:
    from ilcpmac.core.errors import BenchFormatError
    from ilcpmac.core.schema import parse_section

    def parse(table: str, data: dict):
        cls, error = (LimitSettings, ConfigError) if table == "limits" else (MotorTable, BenchFormatError)
        return parse_section(data, cls, f"{table}.toml", table, error=error)

    return "import ilcpmac.core.schema", parse, (LimitSettings, MotorTable)


def pydantic_kit() -> tuple[str, Callable, tuple]:
    from pydantic import BaseModel, ConfigDict, Field

    class Limits(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
        max_current_a: float = Field(30.0, gt=0)
        max_torque_nm: float = Field(8.0, gt=0)
        max_speed_hz: float = Field(1.5, gt=0)
        max_correction_nm: float = Field(1.5, gt=0)
        max_scale_deviation: float = Field(0.1, gt=0, lt=1)
        max_offset_deviation_a: float = Field(0.5, gt=0)
        max_torque_gain_deviation: float = Field(0.1, gt=0, lt=1)
        max_samples_per_trial: int = Field(2_000_000, gt=0)
        max_trial_duration_s: float = Field(600.0, gt=0)

    class Motor(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
        pole_pairs: int = Field(ge=1, le=256)
        slots: int = Field(ge=3, le=2048)
        counts_per_rev: int = Field(ge=4, le=2**20)
        inertia: float = Field(ge=1e-8, le=1e4, allow_inf_nan=False)
        backemf_file: str
        torque_sensor: bool = True
        timer_resolution_s: float | None = Field(None, gt=0, le=1e-3)
        mirrored: bool = False

    models = {"limits": Limits, "motor": Motor}
    return ("from pydantic import BaseModel, ConfigDict, Field",
            lambda table, data: models[table].model_validate(data), (Limits, Motor))


def msgspec_kit() -> tuple[str, Callable, tuple]:
    import msgspec
    from msgspec import Meta

    class Limits(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
        max_current_a: Annotated[float, Meta(gt=0)] = 30.0
        max_torque_nm: Annotated[float, Meta(gt=0)] = 8.0
        max_speed_hz: Annotated[float, Meta(gt=0)] = 1.5
        max_correction_nm: Annotated[float, Meta(gt=0)] = 1.5
        max_scale_deviation: Annotated[float, Meta(gt=0, lt=1)] = 0.1
        max_offset_deviation_a: Annotated[float, Meta(gt=0)] = 0.5
        max_torque_gain_deviation: Annotated[float, Meta(gt=0, lt=1)] = 0.1
        max_samples_per_trial: Annotated[int, Meta(gt=0)] = 2_000_000
        max_trial_duration_s: Annotated[float, Meta(gt=0)] = 600.0

    class Motor(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
        pole_pairs: Annotated[int, Meta(ge=1, le=256)]
        slots: Annotated[int, Meta(ge=3, le=2048)]
        counts_per_rev: Annotated[int, Meta(ge=4, le=2**20)]
        inertia: Annotated[float, Meta(ge=1e-8, le=1e4)]
        backemf_file: str
        torque_sensor: bool = True
        timer_resolution_s: Annotated[float, Meta(gt=0, le=1e-3)] | None = None
        mirrored: bool = False

    models = {"limits": Limits, "motor": Motor}
    return ("import msgspec", lambda table, data: msgspec.convert(data, models[table], strict=True),
            (Limits, Motor))


def cattrs_kit() -> tuple[str, Callable, tuple]:
    import attrs
    import cattrs
    from attrs import validators as v

    positive = [v.instance_of(float), v.gt(0)]
    fraction = [v.instance_of(float), v.gt(0), v.lt(1)]

    @attrs.frozen
    class Limits:
        max_current_a: float = attrs.field(default=30.0, validator=positive)
        max_torque_nm: float = attrs.field(default=8.0, validator=positive)
        max_speed_hz: float = attrs.field(default=1.5, validator=positive)
        max_correction_nm: float = attrs.field(default=1.5, validator=positive)
        max_scale_deviation: float = attrs.field(default=0.1, validator=fraction)
        max_offset_deviation_a: float = attrs.field(default=0.5, validator=positive)
        max_torque_gain_deviation: float = attrs.field(default=0.1, validator=fraction)
        max_samples_per_trial: int = attrs.field(default=2_000_000, validator=[v.instance_of(int), v.gt(0)])
        max_trial_duration_s: float = attrs.field(default=600.0, validator=positive)

    @attrs.frozen
    class Motor:
        pole_pairs: int = attrs.field(validator=[v.instance_of(int), v.ge(1), v.le(256)])
        slots: int = attrs.field(validator=[v.instance_of(int), v.ge(3), v.le(2048)])
        counts_per_rev: int = attrs.field(validator=[v.instance_of(int), v.ge(4), v.le(2**20)])
        inertia: float = attrs.field(validator=[v.instance_of(float), v.ge(1e-8), v.le(1e4)])
        backemf_file: str = attrs.field(validator=v.instance_of(str))
        torque_sensor: bool = attrs.field(default=True, validator=v.instance_of(bool))
        timer_resolution_s: float | None = attrs.field(
            default=None, validator=v.optional([v.instance_of(float), v.gt(0), v.le(1e-3)]))
        mirrored: bool = attrs.field(default=False, validator=v.instance_of(bool))

    converter = cattrs.Converter(forbid_extra_keys=True)
    models = {"limits": Limits, "motor": Motor}
    return "import attrs, cattrs", lambda table, data: converter.structure(data, models[table]), (Limits, Motor)


KITS = {"ours": (None, ours), "pydantic v2": ("pydantic", pydantic_kit), "msgspec": ("msgspec", msgspec_kit),
        "cattrs": ("cattrs", cattrs_kit)}


def said(parse: Callable, table: str, data: dict) -> str:
    """What ``parse`` says of ``data``: its message cut to 60 characters, and its lines."""
    try:
        parse(table, data)
    except Exception as e:  # noqa: BLE001 - each library raises its own
        text = str(e) or type(e).__name__
        lines = text.count("\n") + 1
        return f"{lines} line{'s' * (lines != 1)}: {' | '.join(text.split(chr(10)))[:90]!r}"
    return "accepted (wrong!)"


def main() -> None:
    kit_lines = sum(1 for line in Path(sys.modules["ilcpmac.core.schema"].__file__).read_text().splitlines()
                    if line.strip())
    print(f"import times after `{BASELINE}`, best of 5")
    for name, (module, make) in KITS.items():
        if module is not None and importlib.util.find_spec(module) is None:
            print(f"\n{name}: not installed, skipped (pip install {module})")
            continue
        statement, parse, classes = make()
        ms = import_ms(statement, "ilcpmac.core.schema" if module is None else None)
        print(f"\n{name}: import {ms:.1f} ms; declarations "
              f"{code_lines(*classes)} lines; kit "
              f"{f'{kit_lines} lines (src/ilcpmac/core/schema.py)' if module is None else 'the library'}")
        for table, cases in CASES.items():
            for case, change in cases.items():
                data = (MOTOR if table == "motor" else {}) | change
                print(f"  [{table}] {case:13} {said(parse, table, data)}")


if __name__ == "__main__":
    main()
