"""The moteus backend through mjbots' own library (its Controller, Stream and Transport) on the emulated moteus."""

from __future__ import annotations

import asyncio
import math
import signal

import numpy as np
import pytest

moteus = pytest.importorskip("moteus")

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from moteus import multiplex as mp  # noqa: E402
from moteus.transport_device import Frame, TransportDevice  # noqa: E402

from ilcpmac.backends.drive import DriveBackend, DriveLimits  # noqa: E402
from ilcpmac.backends.moteus.backend import (  # noqa: E402
    MoteusBackend,  # noqa: E402
    moteus_description,
    unwrapped_revolutions,
)
from ilcpmac.backends.moteus.emulated import EmulatedMoteusDevice  # noqa: E402
from ilcpmac.backends.moteus.settings import parse_settings  # noqa: E402
from ilcpmac.backends.registry import BackendSetup  # noqa: E402
from ilcpmac.config import load_config, packaged_config  # noqa: E402
from ilcpmac.core.errors import BackendError, ConfigError, SafetyError  # noqa: E402
from ilcpmac.core.records import DriveTrialRequest  # noqa: E402
from ilcpmac.export import MOTEUS_TABLE_SIZE  # noqa: E402
from ilcpmac.sim.moteus_drive import MODES, DriveSpec, EmulatedDrive  # noqa: E402

STOPPED, FAULT, POSITION, TIMEOUT = MODES["stopped"], MODES["fault"], MODES["position"], MODES["timeout"]
RATE_HZ = 1000.0


@pytest.fixture(scope="module")
def config():
    return load_config(packaged_config("seed-bench.toml"))


@pytest.fixture(scope="module")
def backend(config):
    """One emulated moteus for the tests that only run trials on it (its flash checked untouched at the end)."""
    b = MoteusBackend.from_setup(BackendSetup(config, options={"transport": "emulated", "query_rate_hz": RATE_HZ}))
    flash = dict(b.device.drive.flash)
    yield b
    assert b.device.drive.flash == flash
    b.close()


def _backend(config, spec: DriveSpec | None = None, write_config: bool = False, **device) -> MoteusBackend:
    """An emulated moteus on a drive of ``spec``, its device built with the hooks ``device``."""
    settings = parse_settings({"transport": "emulated", "query_rate_hz": RATE_HZ}, "test.toml")
    drive = EmulatedDrive(config.simulated_model(), spec or DriveSpec(), seed=3)
    return MoteusBackend(settings, moteus_description(config, RATE_HZ), EmulatedMoteusDevice(drive, seed=4, **device),
                         write_config=write_config)


def _request(speed_hz: float = 2.0, seconds: float = 0.5, seed: int = 0, table: np.ndarray | None = None,
             scale_a: float = 0.01) -> DriveTrialRequest:
    values = np.zeros(MOTEUS_TABLE_SIZE, np.int64) if table is None else table
    return DriveTrialRequest(speed_hz=speed_hz, settle_s=0.3, seconds=seconds, table_values=values,
                             table_scale_a=scale_a, seed=seed)


class InPositionMode:
    """An ``on_transaction`` hook that calls ``act`` once, ``after`` transactions into position mode."""

    def __init__(self, act, after: int = 100) -> None:
        self.act, self.after, self.device, self.seen = act, after, None, 0

    def __call__(self, n: int) -> None:
        if self.device.drive.status().mode == POSITION:
            self.seen += 1
            if self.seen == self.after:
                self.act()


def _hooked(config, act, **kw) -> MoteusBackend:
    hook = InPositionMode(act)
    b = _backend(config, on_transaction=hook, **kw)
    hook.device = b.device
    return b


class SlowHost(asyncio.SelectorEventLoop):
    """An event loop on a host so loaded that 20 ms of real time pass between any two looks at its clock."""

    def __init__(self) -> None:
        super().__init__()
        self._late_s = 0.0

    def time(self) -> float:
        self._late_s += 0.02
        return super().time() + self._late_s


def test_how_loaded_the_host_is_loses_no_poll_of_the_emulated_drive_nor_changes_its_rows(config):
    """The emulated transport answers within the call, on its own clock: a poll's reply waited for in real time
    (10 ms, poll_timeout_s) was dropped on a loaded machine, and the telemetry flush after ``tel stop`` read for
    0.2 s of real time, each read advancing the drive's clock: two runs of one config differed."""
    settings = parse_settings({"transport": "emulated", "query_rate_hz": RATE_HZ}, "test.toml")
    trials = []
    for loop in (SlowHost(), asyncio.new_event_loop()):
        drive = EmulatedDrive(config.simulated_model(), DriveSpec(), seed=3)
        b = MoteusBackend(settings, moteus_description(config, RATE_HZ), EmulatedMoteusDevice(drive, seed=4),
                          loop=loop)
        trials.append(b.run_drive_trial(_request(seconds=0.1)))
        b.close()
    slow, normal = trials
    assert slow.lost == 0 and slow.polls == slow.data.time_s.size == pytest.approx(0.1 * RATE_HZ, abs=2)
    np.testing.assert_array_equal(slow.data.time_s, normal.data.time_s)
    np.testing.assert_array_equal(slow.data.position_counts, normal.data.position_counts)


def test_is_a_drive_backend(backend):
    assert isinstance(backend, DriveBackend)
    assert backend.max_parallel_trials == 1
    motor = backend.describe().motor
    assert not motor.torque_sensor and motor.log_rate_hz == RATE_HZ


def test_forward_and_reverse_trials(backend, config):
    cpr = config.bench.counts_per_rev
    for speed_hz in (2.0, -2.0):
        trial = backend.run_drive_trial(_request(speed_hz))
        data = trial.data
        assert trial.lost == 0 and trial.polls == data.time_s.size
        assert abs(data.time_s.size - RATE_HZ * 0.5) <= 2
        assert np.all(np.diff(data.time_s) > 0)
        speed = (data.position_counts[-1] - data.position_counts[0]) / (data.time_s[-1] - data.time_s[0]) / cpr
        assert speed == pytest.approx(speed_hz, rel=0.03)
        assert np.all(np.sign(np.diff(data.position_counts)) == np.sign(speed_hz))
        assert trial.true_residual_nm.shape == (cpr,) and trial.true_position_torque_nm.shape == (cpr,)
        assert math.isfinite(trial.max_temperature_c)
        assert backend.device.drive.status().mode == STOPPED


def test_table_uploaded_is_what_the_drive_holds(backend):
    rng = np.random.default_rng(11)
    drive = backend.device.drive
    for scale_a in (0.02, 0.005):
        table = rng.integers(-127, 128, MOTEUS_TABLE_SIZE)
        table[:512] = 3  # the second table differs from the first only in its second half
        backend.run_drive_trial(_request(seconds=0.05, table=table, scale_a=scale_a))
        assert drive.config["motor.cogging_dq_scale"] == scale_a
        assert [drive.config[f"motor.cogging_dq_comp.{k}"] for k in range(MOTEUS_TABLE_SIZE)] == table.tolist()


def test_limits_read_from_the_drive(config):
    b = _backend(config, DriveSpec(max_current_a=7.0, max_velocity_hz=5.0, fault_temperature_c=60.0,
                                   motor_fault_temperature_c=50.0))
    assert b.drive_limits() == DriveLimits(7.0, 5.0, 50.0, config.model.controller.bandwidth_hz)
    b.close()


def test_beyond_max_velocity_refused_before_any_motion(config):
    modes = []
    b = _backend(config, DriveSpec(max_velocity_hz=5.0), on_transaction=lambda n: modes.append(
        b.device.drive.status().mode))
    with pytest.raises(SafetyError, match="servo.max_velocity"):
        b.run_drive_trial(_request(speed_hz=-6.0))
    assert modes and set(modes) == {STOPPED}
    b.close()


def test_an_exception_in_the_transport_stops_the_drive(config):
    def fail():
        raise OSError("emulated serial port gone")

    b = _hooked(config, fail)
    with pytest.raises(BackendError, match="OSError: emulated serial port gone") as e:
        b.run_drive_trial(_request())
    assert "\n" not in str(e.value)
    assert b.device.drive.status().mode == STOPPED
    b.close()


def test_a_fault_stops_the_trial_and_names_it(config):
    b = _backend(config, DriveSpec(fault_temperature_c=25.001))
    with pytest.raises(BackendError, match=r"kOverTemperature \(38\)"):
        b.run_drive_trial(_request(seconds=2.0))
    assert b.device.drive.status().mode in (STOPPED, FAULT)  # stopped, and faulted again while still too hot
    b.close()


def test_keyboard_interrupt_inside_the_transport_stops_the_drive(config):
    def interrupt():
        raise KeyboardInterrupt

    b = _hooked(config, interrupt)
    with pytest.raises(KeyboardInterrupt):
        b.run_drive_trial(_request())
    assert b.device.drive.status().mode == STOPPED
    b.close()


def test_ctrl_c_cancels_the_trial_and_stops_the_drive(config):
    """A real SIGINT, with Python's handler of a process started from a terminal: one started in the background
    (``command &`` in a script, as CI may run the suite) inherits SIGINT ignored, and nothing would be raised."""
    b = _hooked(config, lambda: signal.raise_signal(signal.SIGINT))
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            b.run_drive_trial(_request())
    finally:
        signal.signal(signal.SIGINT, before)
    assert b.device.drive.status().mode == STOPPED
    b.close()


def test_lost_replies_end_the_trial_with_a_stop(config):
    hook = InPositionMode(lambda: setattr(b.device, "mute_at", b.device.transactions))
    b = _backend(config, on_transaction=hook)
    hook.device = b.device
    with pytest.raises(BackendError, match="connection lost.*not confirmed"):
        b.run_drive_trial(_request())
    assert b.device.drive.status().mode == STOPPED  # the stop went out, only its reply was lost
    b.close()


def test_a_cut_cable_leaves_the_watchdog_to_stop_the_drive(config):
    hook = InPositionMode(lambda: setattr(b.device, "cut_at", b.device.transactions))
    b = _backend(config, on_transaction=hook)
    hook.device = b.device
    with pytest.raises(BackendError, match="connection lost"):
        b.run_drive_trial(_request())
    drive = b.device.drive
    drive.advance(b.settings.watchdog_timeout_s)
    assert drive.status().mode == TIMEOUT
    b.device.cut_at = None
    b.close()


def test_the_watchdog_stops_a_drive_whose_host_vanished(config):
    device = EmulatedMoteusDevice(EmulatedDrive(config.simulated_model(), DriveSpec(), seed=1))
    controller = moteus.Controller(id=1, transport=moteus.Transport(device))

    async def vanish():
        reply = await controller.set_position(position=math.nan, velocity=1.0, watchdog_timeout=0.05, query=True)
        assert reply.values[moteus.Register.MODE] == POSITION
        await device.sleep(0.04)
        assert device.drive.status().mode == POSITION
        await device.sleep(0.02)

    asyncio.run(vanish())
    assert device.drive.status().mode == TIMEOUT


def test_flash_written_only_with_write_config(config):
    table = np.full(MOTEUS_TABLE_SIZE, -4, np.int64)
    b = _backend(config)
    flash = dict(b.device.drive.flash)
    b.run_drive_trial(_request(seconds=0.05, table=table))
    with pytest.raises(SafetyError, match="--write-config not given: nothing written to the drive's flash"):
        b.store_table(_request(table=table))
    assert b.device.drive.flash == flash
    b.close()
    b = _backend(config, write_config=True)
    b.store_table(_request(table=table, scale_a=0.03))
    assert b.device.drive.flash["motor.cogging_dq_scale"] == 0.03
    assert b.device.drive.flash["motor.cogging_dq_comp.1023"] == -4
    b.close()


def test_grid_trials_refused(backend):
    with pytest.raises(BackendError, match="needs a load"):
        backend.run_trial(None)


@pytest.mark.parametrize("options, key", [
    ({"id": 200}, "[backends.moteus] id"),
    ({"transport": "usb"}, "[backends.moteus] transport"),
    ({"query_rate_hz": 5.0}, "[backends.moteus] query_rate_hz"),
    ({"speed": 1}, "[backends.moteus] unknown key 'speed'"),
    ({"transport": "emulated", "emulated": {"round_trip": 1}}, "[backends.moteus.emulated] unknown key"),
    ({"transport": "emulated", "emulated": {"max_current_a": -1.0}}, "[backends.moteus.emulated] max_current_a"),
    ({"transport": "emulated", "emulated": {"jitter_s": 1.0}}, "[backends.moteus.emulated] jitter_s"),
    ({"emulated": {}}, "transport is 'fdcanusb'"),
])
def test_settings_errors_name_the_key(options, key):
    with pytest.raises(ConfigError) as e:
        parse_settings(options, "bench.toml")
    assert str(e.value).startswith("bench.toml: ") and key in str(e.value) and "\n" not in str(e.value)


def test_address_only_for_a_device(config):
    with pytest.raises(ConfigError, match="--address 1.2.3.4:5: the moteus backend's emulated transport"):
        MoteusBackend.from_setup(BackendSetup(config, address="1.2.3.4:5", options={"transport": "emulated"}))


def test_unwrapping_across_lost_polls():
    time_s = np.array([0.0, 0.001, 0.030, 0.031])  # 28 polls lost in the middle: 0.56 rev at 20 rev/s
    true = 0.95 + 20.0 * time_s
    got = unwrapped_revolutions(true % 1.0, np.full(4, 20.0), time_s)
    np.testing.assert_allclose(got, true - 0.95 + (0.95 % 1.0))


_DRIVE_DEVICE: list[EmulatedMoteusDevice] = []


def _fuzzed_device(config) -> EmulatedMoteusDevice:
    if not _DRIVE_DEVICE:
        _DRIVE_DEVICE.append(EmulatedMoteusDevice(EmulatedDrive(config.simulated_model(), DriveSpec(), seed=5)))
    return _DRIVE_DEVICE[0]


@settings(max_examples=300, deadline=None, derandomize=True)
@given(arbitration_id=st.one_of(st.integers(0, 2**29 - 1), st.sampled_from([0x8001, 0x0001, 0x807F])),
       data=st.one_of(st.binary(max_size=64),
                      st.lists(st.sampled_from([0x01, 0x00, 0x0A, 0x10, 0x1F, 0x11, 0x40, 0x42, 0x0C, 0x20, 0x21,
                                                0x27, 0x50, 0xFF, 0x80, 0x7F]), max_size=64).map(bytes)))
def test_garbage_frames_never_break_the_device(config, arbitration_id, data):
    device = _fuzzed_device(config)
    request = TransportDevice.Request(frame=Frame(arbitration_id=arbitration_id, data=data),
                                      frame_filter=lambda f: True)
    asyncio.run(device.transaction([request]))
    for reply in request.responses:
        assert len(reply.data) <= 64
        list(mp.parse_frame(reply.data))
    device.drive.command_stop()


def test_without_the_moteus_library_the_backend_says_what_to_install(monkeypatch):
    from ilcpmac.backends.moteus import from_setup
    from ilcpmac.core.errors import ConfigError

    monkeypatch.setitem(__import__("sys").modules, "moteus", None)  # as if not installed
    with pytest.raises(ConfigError, match=r"needs mjbots' moteus library, an optional extra: pip install "
                                          r"'ilcpmac\[moteus\]'"):
        from_setup(None)  # type: ignore[arg-type]


def test_a_rotor_still_faster_than_the_trial_is_never_commanded_beyond_the_speed_checked(config):
    """The velocity command ramped from the rotor's speed as the drive reports it: a rotor still coasting at 3 Hz
    from before made the first commands of a 0.5 Hz trial 3 Hz, a speed the guard never checked (and tripped the
    current limit). Now the drive is held stopped while it coasts down, and where it does not within the settling
    time the trial is refused in one line, nothing beyond 0.5 Hz commanded."""
    b = _backend(config)
    drive = b.device.drive
    drive.command_position(3.0, watchdog_timeout_s=math.nan)
    drive.advance(1.0)
    assert drive.status().velocity_hz > 2.5
    commanded: list[float] = []
    command = drive.command_position

    def recorded(velocity_hz, **kw):
        commanded.append(abs(velocity_hz))
        command(velocity_hz, **kw)

    drive.command_position = recorded
    with pytest.raises(BackendError, match=r"the rotor still turns at (2\.\d+|3) Hz, faster than the trial's 0\.5 Hz, "
                                           r"after its settling time: let it stop first"):
        b.run_drive_trial(_request(speed_hz=0.5, seconds=0.1))
    # 2.995 Hz reads "3" or "2.99" as the numerics of the installed numpy and numba round it
    assert all(v <= 0.5 for v in commanded) and drive.status().mode == STOPPED
    b.close()
