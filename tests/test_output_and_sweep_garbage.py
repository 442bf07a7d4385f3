"""Limits that hold against wrong data (issue 27, items 9, 11, 12): a sweep's scheduler that is none, magnets
out of range and Ctrl-C; outputs that cannot be written; identifications too uncertain to take."""

from __future__ import annotations

import builtins
import dataclasses
import errno
import json
import os
import re
import signal
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner
from conftest import PHASE_LOG, SEED_CONFIG
from identify_helpers import OTHER_MOTOR, OTHER_SENSORS, other_bench, other_campaign
from test_importer import write_folder, write_phase_log

import ilcpmac.core.files
from ilcpmac.bench.format import write_bench
from ilcpmac.cli import main
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.files import atomic_write
from ilcpmac.identify import TOO_UNCERTAIN, identify_bench
from ilcpmac.sim.reduced import ReducedCampaign, reduced_bench
from ilcpmac.sim.simulator import Simulator
from ilcpmac.sweep.runner import SweepRunError, local_client, remote_client, warm_kernels
from ilcpmac.sweep.spec import KINDS, SweepSpecError, load_spec

# ------------------------------------------------------------------ item 9: the sweep


def _serve(handle: Callable[[socket.socket], None]) -> Iterator[str]:
    """A TCP server on 127.0.0.1 that runs ``handle`` on each connection, in threads; yields its address."""
    server = socket.create_server(("127.0.0.1", 0))

    def accept() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # closed: the test is over
                return
            threading.Thread(target=handle, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()


def _http(conn: socket.socket) -> None:
    """An HTTP server's answer to whatever comes: its first 8 bytes read as a length ask for 3 EiB."""
    with conn:
        conn.recv(65536)
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")


def _echo(conn: socket.socket) -> None:
    """A TCP echo port: Dask's own handshake comes back, then its request instead of an answer."""
    with conn:
        while data := conn.recv(65536):
            conn.sendall(data)


def _silent(conn: socket.socket) -> None:
    """A port that takes everything and answers nothing."""
    with conn:
        while conn.recv(65536):
            pass


@pytest.fixture
def sweep_files(write_config, tmp_path) -> tuple[Path, Path]:
    spec = tmp_path / "spec.toml"
    spec.write_text('[draw."simulator.mechanics.inertia_scale"]\ndistribution = "uniform"\nrelative = 0.2\n')
    return write_config(SMALL_CAMPAIGN), spec


@pytest.mark.parametrize(("handle", "timeout_s", "expected"), [
    (_http, 10.0, r"not a Dask scheduler \(its answer is not Dask's protocol\)"),
    (_echo, 10.0, r"not a Dask scheduler \(it answered Dask's identity request with no scheduler identity\)"),
    (_silent, 0.3, r"no scheduler answered within 0.3 s \(TimeoutError\)"),
])
def test_a_scheduler_address_that_is_no_dask_scheduler_is_one_line(sweep_files, tmp_path, monkeypatch, handle,
                                                                   timeout_s, expected):
    monkeypatch.setattr("ilcpmac.sweep.runner.local_client", lambda workers: pytest.fail("a local cluster"))
    config, spec = sweep_files
    for address in _serve(handle):
        result = CliRunner().invoke(main, ["sweep", str(config), "--spec", str(spec), "--out", str(tmp_path / "out"),
                                           "--scheduler", address, "--connect-timeout", str(timeout_s)])
        assert result.exit_code == 2, result.output
        assert "Traceback" not in result.output and result.exception.__class__ is SystemExit
        assert re.fullmatch(rf"error: --scheduler {address}: {expected}", result.output.splitlines()[-1]), \
            result.output


def test_a_dask_scheduler_passes_the_check_and_a_worker_is_named_as_one():
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      dashboard_address=None) as cluster:
        client = remote_client(cluster.scheduler_address, 10.0)
        assert client.scheduler_info()["type"] == "Scheduler"
        client.close()
        (worker,) = cluster.scheduler.workers
        with pytest.raises(SweepRunError, match=rf"^--scheduler {worker}: not a Dask scheduler \(it "
                                                         r"answered Dask's identity request as a Worker\)$"):
            remote_client(worker, 10.0)


@pytest.mark.parametrize(("magnets", "expected"), [
    # the coefficient that made backemf_scale 7.85 at 80 K, reported "ok"
    ("temperature_rise_k = [0.0, 80.0]\ncoefficient_per_k = 0.0856",
     r"\[magnets\] coefficient_per_k: 0.0856 per K is out of range: the back-EMF's relative change per K, "
     r"within \[-0.005, 0\] \(NdFeB about -0.001\)"),
    ("temperature_rise_k = [0.0, 150.0]\ncoefficient_per_k = -0.004",
     r"\[magnets\] temperature_rise_k: 150 K makes the back-EMF's scale 0.4 \(1 \+ coefficient_per_k x rise\), "
     r"out of \[0.5, 1.5\]"),
    ("temperature_rise_k = [-200.0, 0.0]\ncoefficient_per_k = -0.003",
     r"\[magnets\] temperature_rise_k: -200 K makes the back-EMF's scale 1.6 "),
])
def test_the_magnets_coefficient_and_the_scale_it_makes_are_range_checked(sweep_files, magnets, expected):
    config, spec = sweep_files
    spec.write_text(f"[magnets]\n{magnets}\n")
    with pytest.raises(SweepSpecError) as error:
        load_spec(spec, config)
    assert re.match(rf"{re.escape(str(spec))}: {expected}", str(error.value)) and "\n" not in str(error.value)


def test_ctrl_c_names_the_sweeps_own_resume_command(sweep_files, tmp_path, monkeypatch):
    class Client:
        cluster = None

        def close(self) -> None:
            pass

    def interrupted(self, client, draws, events):
        raise KeyboardInterrupt

    monkeypatch.setattr("ilcpmac.sweep.runner.local_client", lambda workers: Client())
    monkeypatch.setattr("ilcpmac.sweep.runner.SweepRunner.run", interrupted)
    config, spec = sweep_files
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["sweep", str(config), "--spec", str(spec), "--out", str(out)])
    assert result.exit_code == 130, result.output
    assert result.output.splitlines()[-1] == (f"error: interrupted; continue the sweep with ilcpmac sweep {config} "
                                              f"--spec {spec} --out {out} --resume")


@pytest.mark.parametrize("kind", KINDS)
def test_the_warm_up_task_of_each_kind_runs(kind):
    """Its trials and learned points at least [campaign]'s fewest revolutions, the encoder's 2 whole ones."""
    warm_kernels(kind)


def test_local_workers_leave_ctrl_c_to_the_sweep():
    """Ctrl-C reaches every process of the terminal's group: the workers ignore it, the sweep closes them."""
    handler = signal.getsignal(signal.SIGINT)
    client = local_client(1)
    try:
        assert set(client.run(signal.getsignal, signal.SIGINT).values()) == {signal.SIG_IGN}
    finally:
        client.close()
        client.cluster.close()
    assert signal.getsignal(signal.SIGINT) is handler


# ------------------------------------------------------------------ item 11: outputs


class _FullDisk:
    """A file being written on a full disk: part of the first write lands, then ENOSPC."""

    def __init__(self, file) -> None:
        self.file = file

    def __enter__(self) -> _FullDisk:
        return self

    def __exit__(self, *exc) -> None:
        self.file.close()

    def write(self, data: bytes) -> int:
        self.file.write(data[: len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str):
        return getattr(self.file, name)


def full_disk(monkeypatch, *prefixes: str) -> None:
    """Make every write of `atomic_write` to a file whose name starts with one of ``prefixes`` hit a full disk."""
    def open_(file, mode="r", *args, **kwargs):
        f = builtins.open(file, mode, *args, **kwargs)
        return _FullDisk(f) if "w" in mode and Path(file).name.startswith(prefixes) else f

    monkeypatch.setattr(ilcpmac.core.files, "open", open_, raising=False)


def test_atomic_write_on_a_full_disk_names_the_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "trial_01.csv"
    path.write_text("the old contents")
    full_disk(monkeypatch, "trial_")
    with pytest.raises(OSError) as error:
        atomic_write(path, b"x" * 1000)
    assert (error.value.errno, error.value.filename) == (errno.ENOSPC, str(path))
    assert [p.name for p in tmp_path.iterdir()] == ["trial_01.csv"] and path.read_text() == "the old contents"


@pytest.fixture(scope="module")
def native(small_model, make_request):
    simulator = Simulator(small_model)
    return simulator.run_trial(make_request(small_model, 2.0, 0.5)), simulator.backemf_counts


@pytest.mark.parametrize("trial_format", ["csv", "parquet"])
def test_import_on_a_full_disk_names_the_trial_file_and_leaves_no_temporary(tmp_path, monkeypatch, native,
                                                                           trial_format):
    trial, backemf = native
    mapping = write_folder(tmp_path, backemf, PHASE_LOG)
    log = write_phase_log(tmp_path / "log.csv", trial, 4e3)
    out = tmp_path / "bench"
    full_disk(monkeypatch, "trial_")
    result = CliRunner().invoke(main, ["import", str(log), "--map", str(mapping), "--out", str(out),
                                       "--format", trial_format])
    assert result.exit_code == 2, result.output
    assert result.output.splitlines()[-1] == f"error: {out / f'trial_01.{trial_format}'}: No space left on device"
    assert not list(out.glob("*.tmp"))


def test_simulate_on_a_full_disk_names_the_trial_file_and_leaves_no_temporary(write_config, tmp_path,
                                                                             monkeypatch):
    config = write_config({**SMALL_CAMPAIGN, "trials": {**SMALL_CAMPAIGN["trials"], "revolutions": 2}})
    out = tmp_path / "bench"
    full_disk(monkeypatch, "trial_")
    result = CliRunner().invoke(main, ["simulate", str(config), "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.output.splitlines()[-1] == f"error: {out / 'trial_01.csv'}: No space left on device"
    assert not list(out.glob("*.tmp"))


def _identify(bench: Path, output: Path | str, *args: str):
    return CliRunner().invoke(main, ["identify", str(bench), "--output", str(output), *args])


@pytest.mark.parametrize(("output", "expected"), [
    (lambda tmp: tmp / "a_file" / "r.json", r"cannot be written \(File exists\)"),
    (lambda tmp: Path("/dev/full"), r"not a regular file \(a folder, FIFO or device is refused\)"),
    (lambda tmp: Path("/proc/version"), r"cannot be written \(.+\)"),
])
def test_identify_refuses_an_output_it_cannot_write_before_the_work(tmp_path, monkeypatch, output, expected):
    (tmp_path / "a_file").write_text("")
    path = output(tmp_path)
    if not path.parent.exists() and path.parent.name != "a_file":
        pytest.skip(f"no {path.parent}")
    monkeypatch.setattr("ilcpmac.identify.identify_bench", lambda *a, **k: pytest.fail("identified first"))
    result = _identify(tmp_path / "bench", path)
    assert result.exit_code == 2, result.output
    assert re.fullmatch(rf"error: {re.escape(str(path))}: {expected}", result.output.strip()), result.output


@pytest.fixture(scope="module")
def bench_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("identify") / "bench"
    write_bench(folder, other_bench()[0])
    return folder


def test_identify_that_cannot_write_its_result_shows_it_and_says_so_in_one_line(bench_folder, tmp_path,
                                                                                monkeypatch):
    output = tmp_path / "r.json"
    full_disk(monkeypatch, "r.json")
    result = _identify(bench_folder, output)
    assert result.exit_code == 2, result.output
    assert "delta*eps" in result.output  # the estimates are shown
    assert result.output.splitlines()[-1] == (f"error: {output}: cannot write the result (No space left on device); "
                                              "the estimates shown above are not saved")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ item 12: the identification


def test_four_revolutions_on_the_encoder_are_enough_for_the_joint_fit(tmp_path):
    """Before: the first encoder pass weighed the excitation against the whole band's noise (the timer's floor at
    2000 harmonics), called it "no excitation", and the report's method gave alpha +-2 and beta +-8 A."""
    bench = tmp_path / "b4"
    simulated = CliRunner().invoke(main, ["simulate", str(SEED_CONFIG), "--out", str(bench), "--revolutions", "4",
                                          "--no-torque-sensor"])
    assert simulated.exit_code == 0, simulated.output
    result = _identify(bench, tmp_path / "r.json", "--torque-source", "encoder")
    assert result.exit_code == 0, result.output
    assert "no excitation" not in result.output and "too uncertain" not in result.output
    estimate, truth = (json.loads(p.read_text()) for p in (tmp_path / "r.json", bench / "truth.json"))
    np.testing.assert_allclose(estimate["alpha"], truth["alpha"], atol=0.01)
    np.testing.assert_allclose(estimate["beta"], truth["beta"], atol=0.01)


@pytest.fixture
def joint_fit_fails(monkeypatch) -> None:
    def fail(*args, **kwargs):
        raise IdentificationError("total system gain (joint fit): failed here")

    monkeypatch.setattr("ilcpmac.identify.fit_joint", fail)


def _weakly_excited() -> tuple:
    return reduced_bench(OTHER_MOTOR, OTHER_SENSORS, other_campaign(
        3, excitation=dataclasses.replace(ReducedCampaign().excitation, fraction=0.002)))


def test_an_estimate_too_uncertain_is_shown_but_not_taken(joint_fit_fails):
    bench, truth = _weakly_excited()
    result = identify_bench(bench)
    report = result.methods["report"]
    assert report.alpha_std.max() > 0.5 * np.abs(report.alpha).min()  # alpha +-1.3
    assert result.alpha is None and result.calibration is None
    assert result.beta is not None  # +-0.015 A: taken
    assert re.fullmatch(r"too uncertain to take \(a standard error beyond 0.5 of the size\): report method's alpha "
                        r"[\d.]+ ± [\d.]+ - the trials' torque noise hides the currents' part of the torque and the "
                        r"joint fit failed \(see the warnings\): more revolutions per trial, or more excitation, "
                        r"narrow it", result.diagnostics[TOO_UNCERTAIN])


def test_identify_of_a_result_too_uncertain_writes_it_and_exits_2(joint_fit_fails, tmp_path):
    write_bench(tmp_path / "bench", _weakly_excited()[0])
    result = _identify(tmp_path / "bench", tmp_path / "r.json")
    assert result.exit_code == 2, result.output
    assert result.output.splitlines()[-1].startswith(f"error: {tmp_path / 'bench'}: too uncertain to take (")
    assert json.loads((tmp_path / "r.json").read_text())["alpha"] is None
    alpha_rows = [line for line in result.output.splitlines() if line.startswith("│ alpha")]
    assert len(alpha_rows) == 3 and not any("*" in row for row in alpha_rows)


@pytest.mark.parametrize(("kind", "name"), [("grid", "truth.json"), ("log", "mapping.toml"), ("log", "truth.json")])
def test_simulate_on_a_full_disk_names_its_other_files_too(write_config, tmp_path, monkeypatch, kind, name):
    """Before: truth.json and mapping.toml were written with write_text: a full disk left half a file and an
    error without its name."""
    config = write_config({**SMALL_CAMPAIGN, "trials": {**SMALL_CAMPAIGN["trials"], "revolutions": 2}})
    out = tmp_path / "bench"
    full_disk(monkeypatch, name)
    args = ["--kind", kind] + (["--duration-s", "4"] if kind == "log" else [])
    result = CliRunner().invoke(main, ["simulate", str(config), "--out", str(out), *args])
    assert result.exit_code == 2, result.output
    assert result.output.splitlines()[-1].startswith(f"error: {out}") and \
        result.output.splitlines()[-1].endswith(f"{name}: No space left on device")
    assert not (out / name).exists() and not list(out.rglob("*.tmp"))
