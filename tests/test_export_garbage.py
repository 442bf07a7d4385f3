"""``ilcpmac export`` on hostile input (issue 27, item 8): a JSON true or false where a number belongs, and a result
whose lists disagree in length, are one line naming the file and the key, exit status 2, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_export import compensation
from test_export_identification import result_json

from ilcpmac.cli import main
from ilcpmac.compensation import Compensation, read_position_table
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import IdentificationResult, boolean_problem


def _set(data: dict, where: tuple, value) -> None:
    for step in where[:-1]:
        data = data[step]
    data[where[-1]] = value


def _refused(source: Path, out: Path, fmt: str, expected: str) -> None:
    """``ilcpmac export source --format fmt``: exactly ``error: expected``, status 2, ``out`` not made."""
    result = CliRunner().invoke(main, ["export", str(source), "--format", fmt, "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.output == f"error: {expected}\n"
    assert not out.exists()


def test_boolean_problem_finds_the_first_boolean_in_order():
    assert boolean_problem([[1.0, 2], [3, [4.0, False]], True]) == "value [1, 1, 1] is false, not a number"
    assert boolean_problem(True) == "is true, not a number"
    assert boolean_problem([[0.5] * 8] * 3) is None and boolean_problem(1) is None and boolean_problem(None) is None
    deep: list = [True]
    for _ in range(5000):  # deeper than Python's recursion limit: no RecursionError
        deep = [deep]
    assert boolean_problem(deep) == f"value {[0] * 5001} is true, not a number"


# ---------------------------------------------------------------- compensation.json


BOOLEANS = [(("tables_nm", 0, 0, 5), True, "key 'tables_nm': value [0, 0, 5] is true, not a number"),
            (("torques_nm", 0), True, "key 'torques_nm': value [0] is true, not a number"),
            (("speeds_hz", 1), False, "key 'speeds_hz': value [1] is false, not a number"),
            (("calibration", "current_scale", 2), True,
             "key 'calibration.current_scale': value [2] is true, not a number"),
            (("calibration", "current_offset", 0), False,
             "key 'calibration.current_offset': value [0] is false, not a number")]


@pytest.mark.parametrize("where, value, message", BOOLEANS)
@pytest.mark.parametrize("fmt", ["json", "csv", "c"])
def test_a_boolean_in_a_compensation_is_refused_naming_file_and_key(tmp_path, where, value, message, fmt):
    data = compensation().to_json()
    if where[0] == "torques_nm":
        data["torques_nm"] = [1.0, 2.0]  # true is 1.0: the grid stays ascending
    _set(data, where, value)
    path = tmp_path / "compensation.json"
    path.write_text(json.dumps(data))
    with pytest.raises(BenchFormatError) as e:
        Compensation.read(path)
    assert str(e.value) == f"{path}: {message}"
    _refused(tmp_path, tmp_path / "out", fmt, f"{path}: {message}")


# ---------------------------------------------------------------- result.json


def _result(tmp_path: Path, where: tuple, value) -> Path:
    path = result_json(tmp_path)
    data = json.loads(path.read_text())
    data["alpha"], data["beta"], data["epsilon"] = [1.01, 0.99, 1.0], [0.1, -0.2, 0.1], 0.97
    _set(data, where, value)
    path.write_text(json.dumps(data))
    return path


RESULT_GARBAGE = [
    (("cogging", "torque", 5), True, "key 'cogging.torque': value [5] is true, not a number"),
    (("alpha", 1), False, "key 'alpha': value [1] is false, not a number"),
    (("beta", 0), True, "key 'beta': value [0] is true, not a number"),
    (("epsilon",), True, "key 'epsilon': is true, not a number"),
    (("calibration", "current_scale", 0), True, "key 'calibration.current_scale': value [0] is true, not a number"),
    (("alpha",), [1.0, 1.0], "key 'alpha': needs 3 values (phases a, b, c), got 2"),
    (("beta",), [0.1, -0.1], "key 'beta': needs 3 values (phases a, b, c), got 2"),
    (("cogging", "count"), list(range(4095)),
     "key 'cogging.count': must be the counts 0 .. 4095, one per value of 'cogging.torque', got 4095 values"),
]


@pytest.mark.parametrize("where, value, message", RESULT_GARBAGE)
def test_garbage_in_a_result_is_refused_naming_file_and_key(tmp_path, where, value, message):
    path = _result(tmp_path, where, value)
    with pytest.raises(BenchFormatError) as e:
        read_position_table(path)
    assert str(e.value) == f"{path}: {message}"
    for fmt in ("json", "csv", "c"):
        _refused(path, tmp_path / fmt, fmt, f"{path}: {message}")


def test_a_result_with_its_own_numbers_still_reads(tmp_path):
    path = _result(tmp_path, ("epsilon",), 1)
    result = IdentificationResult.from_json(json.loads(path.read_text()))
    assert result.epsilon == 1.0 and result.alpha is not None and np.array_equal(result.alpha, [1.01, 0.99, 1.0])
    assert result.cogging_nm is not None and result.cogging_nm.size == 4096
    assert read_position_table(path).counts_per_rev == 4096


# ---------------------------------------------------------------- --scheduler at a port that closes at once


def test_a_scheduler_port_that_closes_at_once_is_said_to_close_not_to_time_out():
    import socket
    import threading

    from ilcpmac.sweep.runner import SweepRunError, remote_client

    server = socket.create_server(("127.0.0.1", 0))
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"

    def close_each() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # the server socket closed: the test is over
                return
            conn.close()

    threading.Thread(target=close_each, daemon=True).start()
    try:
        with pytest.raises(SweepRunError) as e:
            remote_client(address, 60.0)  # far beyond the close, even on a loaded machine: what is said is checked
    finally:
        server.close()
    message = str(e.value)
    assert message.startswith(f"--scheduler {address}: the server closed the connection before answering Dask's "
                              "identity request (") and "within" not in message and "\n" not in message
