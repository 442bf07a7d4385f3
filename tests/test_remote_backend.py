"""RemoteBackend against the bench emulator on 127.0.0.1: equality with the simulator, faults, limits.

Every emulator listens on an ephemeral port and is stopped by a finalizer;
every socket read has a short timeout, so no test can hang.
"""

from __future__ import annotations

import dataclasses
import re
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ilcpmac.backends import Backend
from ilcpmac.backends.base import BenchLimits
from ilcpmac.backends.emulator import BenchEmulator, Fault, FaultPlan
from ilcpmac.backends.protocol import (
    Accept,
    Channel,
    ErrorCode,
    FrameType,
    PeerClosed,
    decode_error,
    decode_request,
    encode_accept,
    encode_describe,
    encode_error,
    encode_request,
    encode_trial,
)
from ilcpmac.backends.remote import RemoteBackend, parse_address
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.campaign.grid import grid_requests
from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import BackendError
from ilcpmac.core.records import TrialData, TrialRequest

ROOT = Path(__file__).resolve().parents[1]
SEED_CONFIG = ROOT / "configs" / "seed-bench.toml"
LIMITS = BenchLimits(max_current_a=30.0, max_torque_nm=8.0, max_speed_hz=1.5)
HOST = "127.0.0.1"


@pytest.fixture(scope="module")
def config():
    """The seed bench with 256 counts per revolution (60 excited harmonics): trials of milliseconds."""
    cfg = load_config(SEED_CONFIG)
    model = dataclasses.replace(cfg.model, encoder=dataclasses.replace(cfg.model.encoder, counts_per_rev=256))
    return dataclasses.replace(cfg, model=model, bench=dataclasses.replace(cfg.bench, counts_per_rev=256),
                               excitation=dataclasses.replace(cfg.excitation, harmonics=60))


@pytest.fixture(scope="module")
def simulator(config) -> SimulatorBackend:
    return SimulatorBackend(config.model, LIMITS, config.grid.warmup_revolutions)


@pytest.fixture(scope="module")
def requests(config) -> list[TrialRequest]:
    """Four grid requests (2 revolutions each), from both ends of the set-point grid."""
    grid = grid_requests(config, config.model.controller.calibration(), seed=11, revolutions=2)
    return [grid[0], grid[len(grid) // 3], grid[2 * len(grid) // 3], grid[-1]]


@pytest.fixture
def emulator(request, simulator, quick_emulator_stop):
    """Start an in-process emulator on an ephemeral port; stopped when the test ends."""

    def start(backend: Backend = simulator, port: int = 0, **options) -> BenchEmulator:
        options = {"chunk_samples": 100, "heartbeat_s": 0.05, "restart_delay_s": 0.05, **options}
        server = BenchEmulator(backend, HOST, port, **options)
        request.addfinalizer(server.stop)
        return server.start()

    return start


@pytest.fixture
def remote(request):
    """A RemoteBackend with short timeouts and back-off; closed when the test ends."""

    def connect(address: str, **options) -> RemoteBackend:
        options = {"connect_timeout_s": 1.0, "read_timeout_s": 0.5, "retries": 2, "backoff_s": 0.02, **options}
        backend = RemoteBackend(address, **options)
        request.addfinalizer(backend.close)
        return backend

    return connect


def assert_same_trial(got: TrialData, expected: TrialData) -> None:
    """Every field equal bit for bit, with the same dtypes."""
    for f in dataclasses.fields(TrialData):
        a, b = getattr(got, f.name), getattr(expected, f.name)
        if f.name == "request":
            continue
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), f.name
        else:
            assert a == b, f.name


# ---------------------------------------------------------------- equality with the simulator


def test_remote_trials_equal_the_simulator_bit_for_bit(emulator, remote, simulator, requests):
    server = emulator()
    backend = remote(server.address)
    assert isinstance(backend, Backend)
    for request in requests:
        trial = backend.run_trial(request)
        assert trial.request is request
        assert trial.i_meas_a is not None and trial.speed_true_rad_s is not None
        assert_same_trial(trial, simulator.run_trial(request))
    assert server.requests_received == len(requests) and server.faults_fired == []


def test_describe_carries_the_simulators_description(emulator, remote, simulator):
    described = remote(emulator().address).describe()
    expected = simulator.describe()
    assert described.motor == expected.motor and described.limits == LIMITS
    assert np.array_equal(described.backemf_nm_per_a, expected.backemf_nm_per_a)
    assert np.array_equal(described.calibration.current_scale, expected.calibration.current_scale)


def test_heartbeats_keep_a_slow_trial_alive(emulator, remote, simulator, requests):
    class Slow:
        def describe(self):
            return simulator.describe()

        def run_trial(self, request):
            time.sleep(0.6)
            return simulator.run_trial(request)

    server = emulator(Slow(), heartbeat_s=0.05)
    trial = remote(server.address, read_timeout_s=0.3).run_trial(requests[0])
    assert_same_trial(trial, simulator.run_trial(requests[0]))


# ---------------------------------------------------------------- progress within a trial


def test_progress_rises_with_the_samples_received_and_ends_at_1(emulator, remote, simulator, requests):
    """Chunks of 100 samples of 2 x 256: every DATA frame reported (no throttle), then the verified end."""
    fractions: list[float] = []
    backend = remote(emulator().address, progress_interval_s=0.0)
    backend.set_progress(fractions.append)
    backend.run_trial(requests[0])
    n = simulator.run_trial(requests[0]).n_samples
    expected = [0.0, *(min(k, n) / 512 for k in range(100, n + 100, 100))]
    assert fractions == expected + ([1.0] if expected[-1] != 1.0 else [])
    assert fractions == sorted(fractions) and len(fractions) >= 7
    backend.set_progress(None)
    backend.run_trial(requests[1])
    assert len(fractions) == len(expected) + (expected[-1] != 1.0)


def test_progress_is_throttled_to_the_start_and_the_end_of_each_trial(emulator, remote, requests):
    fractions: list[float] = []
    backend = remote(emulator().address, progress_interval_s=3600.0)
    backend.set_progress(fractions.append)
    for request in requests[:2]:
        backend.run_trial(request)
    assert fractions == [0.0, 1.0, 0.0, 1.0]


def test_a_retried_trial_reports_its_progress_again_from_0(emulator, remote, requests):
    fractions: list[float] = []
    backend = remote(emulator(faults=FaultPlan(drop=Fault(1))).address, progress_interval_s=0.0, backoff_s=0.01)
    backend.set_progress(fractions.append)
    backend.run_trial(requests[0])
    assert fractions[:3] == [0.0, 100 / 512, 0.0]  # the first attempt dropped after its first DATA frame
    assert fractions[2:] == sorted(fractions[2:]) and fractions[-1] == 1.0


def test_a_paced_emulator_streams_data_with_heartbeats_between(emulator, simulator, requests):
    """At 32 x a bench's pace, DATA frames 100 samples (24 ms) apart, heartbeats every 2 ms between them."""
    server = emulator(pace=32.0, heartbeat_s=0.002)
    types = []
    with socket.create_connection((HOST, server.port), timeout=2.0) as sock:
        channel = Channel(sock, "emulator")
        channel.send(FrameType.HELLO)
        assert channel.recv().type is FrameType.DESCRIBE
        channel.send(FrameType.REQUEST, encode_request(1, requests[0]))
        while (ftype := channel.recv().type) is not FrameType.END_OF_TRIAL:
            types.append(ftype)
    data = [i for i, t in enumerate(types) if t is FrameType.DATA]
    assert len(data) == -(-simulator.run_trial(requests[0]).n_samples // 100)
    assert FrameType.HEARTBEAT in types[data[0]:data[-1]]
    assert set(types) == {FrameType.ACCEPT, FrameType.DATA, FrameType.HEARTBEAT}


def test_stopping_a_paced_emulator_ends_the_trial_it_plays(emulator, requests):
    server = emulator(pace=1e-6)  # its first DATA frame would leave in weeks
    with socket.create_connection((HOST, server.port), timeout=2.0) as sock:
        channel = Channel(sock, "emulator")
        channel.send(FrameType.HELLO)
        assert channel.recv().type is FrameType.DESCRIBE
        channel.send(FrameType.REQUEST, encode_request(1, requests[0]))
        assert channel.recv().type is FrameType.ACCEPT
        server.stop()
        frames = []
        with pytest.raises(PeerClosed):
            while len(frames) < 1000:
                frames.append(channel.recv().type)
    assert set(frames) <= {FrameType.HEARTBEAT}


@pytest.mark.parametrize("pace", [0.0, -1.0, float("inf"), float("nan")])
def test_an_emulator_pace_must_be_positive_and_finite(simulator, pace):
    with pytest.raises(BackendError, match="pace None or positive and finite"):
        BenchEmulator(simulator, HOST, 0, pace=pace)


# ---------------------------------------------------------------- faults


@pytest.mark.parametrize("fault", ["drop", "stall", "corrupt", "restart"])
def test_a_fault_once_ends_in_a_clean_retry(emulator, remote, simulator, requests, fault, caplog):
    server = emulator(faults=FaultPlan(**{fault: Fault(2)}, stall_s=5.0))
    backend = remote(server.address, retries=3, backoff_s=0.1)
    trials = [backend.run_trial(r) for r in requests[:3]]
    for trial, request in zip(trials, requests):
        assert_same_trial(trial, simulator.run_trial(request))
    assert server.faults_fired == [(fault, 2)]
    assert server.requests_received == 4  # trial 2 was sent twice, nothing else repeated
    r = requests[1]
    assert f"trial 2 ({r.torque_setpoint_nm:g} N m, {r.speed_setpoint_hz:g} Hz)" in caplog.text
    assert "attempt 1 of 4 failed" in caplog.text


@pytest.mark.parametrize("fault, reason", [
    ("drop", "closed the connection"),
    ("stall", "timed out waiting for the target"),
    ("corrupt", r"CRC mismatch in frame \d+ \(DATA\)"),
    ("restart", "closed the connection|Connection refused"),
])
def test_a_persistent_fault_ends_in_a_clear_error(emulator, remote, requests, fault, reason):
    server = emulator(faults=FaultPlan(**{fault: Fault(2, repeat=True)}, stall_s=5.0))
    backend = remote(server.address, retries=3)
    backend.run_trial(requests[0])
    r = requests[1]
    with pytest.raises(BackendError, match=rf"^trial 2 \({r.torque_setpoint_nm:g} N m, {r.speed_setpoint_hz:g} Hz\) "
                                           rf"on 127.0.0.1:\d+: gave up after 4 attempts; last failure: .*({reason})"):
        backend.run_trial(requests[1])
    assert 2 <= server.requests_received <= 5


def test_a_wrong_protocol_version_is_a_clear_error_without_retry(emulator, remote, requests):
    server = emulator(faults=FaultPlan(wrong_version=Fault(1)))
    with pytest.raises(BackendError, match=r"^trial 1 \(1 N m, 0.5 Hz\) on 127.0.0.1:\d+: bench target .* "
                                           r"speaks protocol version 2, this end speaks version 1$"):
        remote(server.address).run_trial(requests[0])
    assert server.requests_received == 1


def test_a_failed_trial_is_reported_without_retry(emulator, remote, requests):
    server = emulator()
    with pytest.raises(BackendError, match=r"^trial 1 \(-1 N m, 0.5 Hz\) .*: target error TRIAL_FAILED: "
                                           r"set point -1.0 N m gives .* not enough to turn the rotor"):
        remote(server.address).run_trial(requests[0].with_changes(torque_setpoint_nm=-1.0))
    assert server.requests_received == 1


def test_a_busy_target_is_tried_again(request, remote, simulator, requests):
    """A hand-written target: BUSY on the first connection, the trial on the second."""
    listener = socket.create_server((HOST, 0))
    listener.settimeout(5.0)
    request.addfinalizer(listener.close)

    def serve() -> None:
        for busy in (True, False):
            conn, _ = listener.accept()
            with conn:
                conn.settimeout(5.0)
                channel = Channel(conn, "client")
                channel.recv()
                channel.send(FrameType.DESCRIBE, encode_describe(simulator.describe()))
                trial_id, trial_request = decode_request(channel.recv().payload)
                if busy:
                    channel.send(FrameType.ERROR, encode_error(ErrorCode.BUSY, trial_id, "another client"))
                    continue
                cpr = simulator.describe().motor.counts_per_rev
                channel.send(FrameType.ACCEPT, encode_accept(Accept(trial_id, trial_request.revolutions * cpr)))
                for ftype, parts in encode_trial(trial_id, simulator.run_trial(trial_request), 64):
                    channel.send(ftype, parts)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    request.addfinalizer(lambda: thread.join(5.0))
    trial = remote(f"{HOST}:{listener.getsockname()[1]}").run_trial(requests[0])
    assert_same_trial(trial, simulator.run_trial(requests[0]))


def test_an_unreachable_target_is_a_clear_error(remote):
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind((HOST, 0))
        port = probe.getsockname()[1]
    backend = remote(f"{HOST}:{port}", retries=1)
    with pytest.raises(BackendError, match=rf"^handshake with the bench target on 127.0.0.1:{port}: gave up after "
                                           r"2 attempts; last failure: ConnectionRefusedError"):
        backend.describe()


def _closed_port(request) -> int:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind((HOST, 0))
        return probe.getsockname()[1]


def _peer(request, answer: bytes | None) -> int:
    """A TCP server on 127.0.0.1 that is no bench: it answers every connection's first bytes with ``answer`` and
    closes it, or (None) never says anything; stopped when the test ends."""
    listener = socket.create_server((HOST, 0))
    listener.settimeout(0.05)
    stop, held = threading.Event(), []

    def serve() -> None:
        with listener:
            while not stop.is_set():
                try:
                    conn, _ = listener.accept()
                except TimeoutError:
                    continue
                held.append(conn)
                if answer is not None:
                    conn.settimeout(5.0)
                    conn.recv(64)
                    conn.sendall(answer)
                    conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    request.addfinalizer(lambda: (stop.set(), thread.join(5.0), [c.close() for c in held]))
    return listener.getsockname()[1]


@pytest.mark.parametrize("peer, reason", [
    (_closed_port, "ConnectionRefusedError: Connection refused"),
    (lambda request: _peer(request, b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n"),
     r"bad magic b'HTTP' in a frame header from bench target 127.0.0.1:\d+"),
    (lambda request: _peer(request, None), r"bench target 127.0.0.1:\d+ sent no complete frame in time"),
], ids=["closed port", "HTTP server", "silent server"])
def test_a_failed_handshake_is_one_error_line(request, monkeypatch, caplog, tmp_path, peer, reason):
    """Issue 34, item 17: ``ilcpmac run --backend remote`` against no bench printed each attempt's warning, then
    the error: five lines. The command's own backend, with short deadlines and no back-off."""
    monkeypatch.setattr(RemoteBackend, "from_setup", classmethod(
        lambda cls, setup: cls(setup.address, connect_timeout_s=1.0, read_timeout_s=0.2, backoff_s=0.0)))
    address = f"{HOST}:{peer(request)}"
    caplog.set_level("INFO", logger="ilcpmac.backends.remote")
    done = CliRunner().invoke(main, ["run", "--backend", "remote", "--address", address, "--out",
                                     str(tmp_path / "run")])
    assert done.exit_code == 2
    assert re.fullmatch(rf"error: handshake with the bench target on {address}: gave up after 4 attempts; last "
                        rf"failure: {reason}\n", done.output), done.output
    assert [r.levelname for r in caplog.records if r.name == "ilcpmac.backends.remote"] == ["INFO"] * 4
    assert not (tmp_path / "run").exists()


def test_a_target_that_changes_after_reconnecting_is_refused(emulator, remote, simulator, requests):
    first = emulator()
    backend = remote(first.address)
    backend.run_trial(requests[0])
    first.stop()
    other = SimulatorBackend(simulator.simulator.model, dataclasses.replace(LIMITS, max_torque_nm=9.0))
    emulator(other, port=first.port)
    with pytest.raises(BackendError, match="describes another motor, calibration or limits after reconnecting"):
        backend.run_trial(requests[1])


# ---------------------------------------------------------------- limits


@pytest.mark.parametrize("changes, message", [
    ({"speed_setpoint_hz": 2.0}, r"speed set point 2 Hz exceeds the bench limit of 1.5 Hz"),
    ({"torque_setpoint_nm": 8.5}, r"torque reference 8.\d+ N m at count \d+ .* limit of 8 N m"),
    ({"torque_setpoint_nm": 6.0}, r"current reference -?\d+.\d+ A in phase [abc] at count \d+ .* limit of 15 A"),
    ({"excitation_nm": np.zeros(10)}, r"BAD_REQUEST.*excitation_nm has shape \(10,\)"),
])
def test_requests_beyond_the_limits_are_refused_before_sending(emulator, remote, simulator, requests, changes,
                                                              message):
    server = emulator(SimulatorBackend(simulator.simulator.model, dataclasses.replace(LIMITS, max_current_a=15.0)))
    with pytest.raises(BackendError, match=rf"^trial 1 \(.*\): refused before sending .*{message}"):
        remote(server.address).run_trial(requests[0].with_changes(**changes))
    assert server.requests_received == 0


def test_the_target_refuses_requests_beyond_its_limits_too(emulator, requests):
    server = emulator()
    with socket.create_connection((HOST, server.port), timeout=2.0) as sock:
        channel = Channel(sock, "emulator")
        channel.send(FrameType.HELLO)
        assert channel.recv().type is FrameType.DESCRIBE
        channel.send(FrameType.REQUEST, encode_request(5, requests[0].with_changes(speed_setpoint_hz=3.0)))
        error = decode_error(channel.recv().payload)
        assert (error.code, error.trial_id) == (ErrorCode.LIMIT_EXCEEDED, 5)
        channel.send(FrameType.REQUEST, encode_request(6, requests[0]))  # the connection is still usable
        assert channel.recv().type is FrameType.ACCEPT


@pytest.mark.parametrize("send, code, message", [
    (lambda ch: ch.frame_bytes(FrameType.HELLO, version=2), ErrorCode.VERSION_MISMATCH,
     "this target speaks protocol version 1"),
    (lambda ch: ch.frame_bytes(FrameType.REQUEST, [b"x"]), ErrorCode.UNEXPECTED_FRAME,
     "expected HELLO, got REQUEST"),
    (lambda ch: ch.frame_bytes(FrameType.HELLO)[:-1] + b"\0", ErrorCode.MALFORMED_FRAME,
     "CRC mismatch in frame 0"),
])
def test_the_target_answers_a_bad_first_frame_with_an_error_and_closes(emulator, send, code, message):
    server = emulator()
    with socket.create_connection((HOST, server.port), timeout=2.0) as sock:
        channel = Channel(sock, "emulator")
        channel.send_bytes(send(channel))
        frame = channel.recv()
        error = decode_error(frame.payload)
        assert (frame.type, frame.version, error.code) == (FrameType.ERROR, 1, code)
        assert error.detail.startswith(message)
        assert sock.recv(1) == b""


def test_bad_addresses_are_refused():
    for address in ["localhost", "127.0.0.1:", "127.0.0.1:http", ":5000", "127.0.0.1:70000"]:
        with pytest.raises(BackendError, match="must be HOST:PORT"):
            parse_address(address)
    assert parse_address("[::1]:5000") == ("::1", 5000)


# ---------------------------------------------------------------- ilcpmac emulate


def test_emulate_command_serves_the_simulator(tmp_path, remote):
    config = tmp_path / "bench.toml"
    config.write_text(SEED_CONFIG.read_text().replace("counts_per_rev = 4096", "counts_per_rev = 512")
                      .replace("harmonics = 144", "harmonics = 60"))
    process = subprocess.Popen([sys.executable, "-c", "from ilcpmac.cli import main; main()", "emulate",
                                "--port", "0", "--config", str(config), "--drop", "1"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([process.stdout], [], [], 20.0)
        assert ready, "ilcpmac emulate did not start within 20 s"
        line = process.stdout.readline()
        assert line.startswith("listening on 127.0.0.1:"), process.stderr.read() if process.poll() else line
        backend = remote(line.split()[-1], read_timeout_s=5.0)
        cfg = load_config(config)
        request = grid_requests(cfg, cfg.model.controller.calibration(), seed=3, revolutions=1)[0]
        assert_same_trial(backend.run_trial(request), SimulatorBackend(cfg.model, LIMITS).run_trial(request))
        backend.close()
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(10.0)
        finally:
            process.kill()
    assert process.returncode == 0
    stderr = process.stderr.read()
    assert "fault on trial 1: drop" in stderr and "stopped after 2 trial requests" in stderr


def test_emulate_plays_trials_at_the_pace_asked(monkeypatch):
    seen = {}

    class Recorded:
        def __init__(self, *args, **kwargs) -> None:
            seen.update(kwargs)

        def start(self):
            raise BackendError("recorded")

    monkeypatch.setattr("ilcpmac.backends.emulator.BenchEmulator", Recorded)
    args = ["emulate", "--port", "0", "--config", str(SEED_CONFIG)]
    assert CliRunner().invoke(main, [*args, "--pace", "2.5"]).output == "error: recorded\n"
    assert seen["pace"] == 2.5
    assert CliRunner().invoke(main, args).exit_code == 2 and seen["pace"] is None
    refused = CliRunner().invoke(main, [*args, "--pace", "0"])
    assert refused.exit_code == 2 and "--pace" in refused.output


def test_emulate_reports_a_bad_fault_spec_in_one_line():
    result = CliRunner().invoke(main, ["emulate", "--port", "0", "--config", str(SEED_CONFIG), "--stall", "two"])
    assert result.exit_code == 2
    assert result.output == "error: fault trial 'two' must be N (trial N only) or N+ (trial N and later)\n"


def test_the_emulator_refuses_a_request_of_trial_0(emulator, requests):
    """Section 5.2: a REQUEST's trial_id is at least 1 (0 names no trial in an ERROR)."""
    from ilcpmac.backends.protocol import Channel, FrameType, decode_error, encode_request

    server = emulator()
    host, port = server.address.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5.0) as sock:
        channel = Channel(sock, "emulator")
        channel.send(FrameType.HELLO)
        assert channel.recv().type is FrameType.DESCRIBE
        channel.send(FrameType.REQUEST, encode_request(0, requests[0]))
        frame = channel.recv()
        assert frame.type is FrameType.ERROR
        error = decode_error(frame.payload)
        assert (error.code, error.trial_id) == (ErrorCode.BAD_REQUEST, 0) and "trial_id 0" in str(error)
        channel.send(FrameType.REQUEST, encode_request(1, requests[0]))  # the connection goes on
        assert channel.recv().type is FrameType.ACCEPT


def test_a_target_without_a_torque_sensor_gives_trials_without_torque(emulator, remote, simulator, requests):
    described = simulator.describe()
    described = dataclasses.replace(described, motor=dataclasses.replace(described.motor, torque_sensor=False))

    class NoTorqueSensor:
        max_parallel_trials = 1

        def describe(self):
            return described

        def run_trial(self, request):  # the protocol's DATA has a torque column: such a target sends 0
            trial = simulator.run_trial(request)
            return dataclasses.replace(trial, torque_nm=np.zeros_like(trial.torque_nm))

    backend = remote(emulator(NoTorqueSensor()).address)
    assert backend.describe().motor.torque_sensor is False
    trial = backend.run_trial(requests[0])
    assert trial.torque_nm is None
    np.testing.assert_array_equal(trial.time_s, simulator.run_trial(requests[0]).time_s)
