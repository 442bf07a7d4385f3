"""examples/log_moteus.py and examples/log_odrive.py without hardware and without their drive libraries.

Each script is imported as a module (with its library made unimportable: it must import without it), its command
line parsed, and its logging loop driven by a fake drive on a fake clock: a rotor turning at a constant speed with
a position-locked q current, replies 0.4-1.6 ms apart. What it writes must import with ``ilcpmac import`` as it
stands, and the imported torque reference K . i_ref must be K_t times the fake's q current at each count (the
mapping's position unit, wrap and back-EMF are right). Every way out (the end, an error of the drive, Ctrl-C,
a cancelled task) stops the motor or idles the axis, and the CSV keeps the rows logged.
"""

from __future__ import annotations

import asyncio
import importlib.util
import math
import sys
import tomllib
from pathlib import Path
from types import ModuleType, SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

import ilcpmac.cli.import_  # noqa: F401  (registers the command on main)
from ilcpmac.bench.format import read_bench
from ilcpmac.bench.importer import read_mapping
from ilcpmac.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: the fake motor: pole pairs, slots (cogging order lcm(12, 14) = 84), K_t, inertia, rotor speed
POLE_PAIRS, SLOTS, TORQUE_CONSTANT, INERTIA = 7, 12, 0.09, 6e-5
SPEED_HZ = 0.5
#: the fake q current: a mean and position-locked harmonics (order -> A, phase rad)
I_Q_MEAN_A = 0.4
I_Q_RIPPLE = {84: (0.05, 0.3), 7: (0.02, -1.0)}
#: replies come this far apart, s (uniform)
REPLY_GAP_S = (0.4e-3, 1.6e-3)
#: the ODrive's encoder counts per revolution
ENCODER_CPR = 8192
#: the largest angle between two replies, rad, and what linear interpolation over it misses of the q current, A
#: (|i_q''| step^2 / 8)
LARGEST_STEP_RAD = 2 * np.pi * SPEED_HZ * REPLY_GAP_S[1]
INTERPOLATION_A = sum(a * h**2 for h, (a, _) in I_Q_RIPPLE.items()) * LARGEST_STEP_RAD**2 / 8


def load(name: str, library: str) -> ModuleType:
    """examples/NAME.py as a module, imported with ``library`` unimportable."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    saved = sys.modules.get(library)
    sys.modules[library] = None  # import LIBRARY raises ImportError
    try:
        spec.loader.exec_module(module)
    finally:
        if saved is None:
            del sys.modules[library]
        else:
            sys.modules[library] = saved
    return module


@pytest.fixture(scope="module")
def moteus_script() -> ModuleType:
    return load("log_moteus", "moteus")


@pytest.fixture(scope="module")
def odrive_script() -> ModuleType:
    return load("log_odrive", "odrive")


def i_q_at(theta_rad: np.ndarray | float) -> np.ndarray | float:
    return I_Q_MEAN_A + sum(a * np.cos(h * theta_rad + phase) for h, (a, phase) in I_Q_RIPPLE.items())


class Rotor:
    """The fake drive's physics and clock: the rotor at SPEED_HZ from angle 0.3 rad; each exchange takes a seeded
    random time, the drive sampling half-way through."""

    def __init__(self, seed: int) -> None:
        self.now = 100.0
        self.rng = np.random.default_rng(seed)
        self.exchanges = 0

    def clock(self) -> float:
        return self.now

    def exchange(self) -> float:
        """Half an exchange, the drive's sample (the rotor's angle, rad), the other half."""
        gap = self.rng.uniform(*REPLY_GAP_S)
        self.now += gap / 2
        theta = 0.3 + 2 * np.pi * SPEED_HZ * (self.now - 100.0)
        self.now += gap / 2
        self.exchanges += 1
        return theta


# ---- moteus

#: the fake's register numbers (moteus.Register's) and halting modes (moteus.Mode.FAULT, TIMEOUT)
MODE, Q_CURRENT, TEMPERATURE, FAULT = 0x000, 0x004, 0x00E, 0x00F
ENCODER_POSITION = {0: 0x050, 1: 0x052, 2: 0x054}
HALTED = (1, 11)


class FakeMoteus:
    """A moteus Controller's set_position / set_stop, replying as the firmware does (the commutation encoder's
    position in rev within [0, 1)); ``fail`` (exchange -> exception) makes one exchange raise instead."""

    def __init__(self, rotor: Rotor, source: int = 0, fail: dict[int, BaseException] | None = None,
                 mode_at: dict[int, int] | None = None) -> None:
        self.rotor, self.source, self.fail, self.mode_at = rotor, source, fail or {}, mode_at or {}
        self.commands: list[dict] = []
        self.stops: list[int] = []

    async def set_position(self, **command):
        self.commands.append(command)
        if self.rotor.exchanges in self.fail:
            raise self.fail[self.rotor.exchanges]
        mode = self.mode_at.get(self.rotor.exchanges, 10)
        theta = self.rotor.exchange()
        return SimpleNamespace(values={
            MODE: mode, ENCODER_POSITION[self.source]: (theta / (2 * np.pi)) % 1.0,
            ENCODER_POSITION[self.source] + 1: SPEED_HZ, Q_CURRENT: i_q_at(theta), TEMPERATURE: 31.5,
            FAULT: 0 if mode == 10 else 39})

    async def set_stop(self):
        self.stops.append(self.rotor.exchanges)


class FakeStream:
    """moteus's diagnostic stream answering ``conf get NAME`` from ``config``."""

    def __init__(self, config: dict[str, float]) -> None:
        self.config = config

    async def command(self, data: bytes, allow_any_response: bool = False) -> bytes:
        assert allow_any_response and data.startswith(b"conf get ")
        return f"{self.config[data.decode().split()[2]]:g}".encode()


def moteus_config(**changes: float) -> dict[str, float]:
    return {"motor.poles": 2 * POLE_PAIRS, "motor_position.rotor_to_output_ratio": 0.25,
            "motor_position.commutation_source": 0, "motor.cogging_dq_scale": 0.0} | changes


def run_moteus(script: ModuleType, tmp_path: Path, drive: FakeMoteus, config: dict[str, float],
               *options: str):
    args = script.parse_args(["--slots", str(SLOTS), "--inertia-kgm2", str(INERTIA), "--torque-constant",
                              str(TORQUE_CONSTANT), "--speed-hz", str(SPEED_HZ), "--duration-s", "3", "--settle-s",
                              "0.5", "--counts-per-rev", "1024", "--out", str(tmp_path / "log"), *options])
    connected = []

    def connect(source: int):
        connected.append(source)
        registers = script.Registers(ENCODER_POSITION[source], ENCODER_POSITION[source] + 1, Q_CURRENT, TEMPERATURE,
                                     FAULT, MODE, HALTED)
        return drive, registers

    log = asyncio.run(script.run(FakeStream(config), connect, args, drive.rotor.clock))
    return log, connected


def imported(tmp_path: Path, log: str, mapping: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """``ilcpmac import`` of the script's log and mapping; the trial's counts, torque reference K . i_ref and the
    bench's counts per revolution."""
    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["import", str(tmp_path / "log" / log), "--map", str(mapping), "--out",
                                       str(out)])
    assert result.exit_code == 0, result.output
    bench = read_bench(out)
    (trial,) = bench.trials
    cpr = bench.motor.counts_per_rev
    torque = np.sum(bench.backemf_nm_per_a[trial.count % cpr] * trial.i_ref_a, axis=1)
    return trial.count, torque, cpr


def test_the_scripts_import_without_their_libraries(moteus_script, odrive_script):
    """`load` makes each library unimportable while its script imports (a script importing it at the top fails
    there), and neither holds it afterwards; whether another test imported the library (the moteus backend's do)
    does not matter."""
    assert callable(moteus_script.main) and callable(odrive_script.main)
    for script in (moteus_script, odrive_script):
        held = [name for name, value in vars(script).items() if isinstance(value, ModuleType)
                and value.__name__.split(".")[0] in ("moteus", "odrive")]
        assert held == [], held


def test_moteus_command_line(moteus_script, capsys):
    args = moteus_script.parse_args(["--slots", "12", "--inertia-kgm2", "6e-5", "--torque-constant", "0.09"])
    assert (args.id, args.speed_hz, args.duration_s, args.settle_s, args.max_torque_nm, args.counts_per_rev,
            args.out) == (1, 0.5, 20.0, 2.0, None, 4096, Path("moteus-log"))
    for bad, option in ((["--speed-hz", "0"], "--speed-hz"), (["--inertia-kgm2", "nan"], "--inertia-kgm2"),
                        (["--settle-s", "-1"], "--settle-s"), (["--slots", "1.5"], "--slots")):
        with pytest.raises(SystemExit) as stop:
            moteus_script.parse_args(["--slots", "12", "--inertia-kgm2", "6e-5", "--torque-constant", "0.09", *bad])
        assert stop.value.code == 2 and option in capsys.readouterr().err
    with pytest.raises(SystemExit):
        moteus_script.parse_args(["--inertia-kgm2", "6e-5", "--torque-constant", "0.09"])
    assert "--slots" in capsys.readouterr().err


def test_moteus_log_imports_as_the_commutation_position_and_q_current(moteus_script, tmp_path):
    drive = FakeMoteus(Rotor(seed=3), source=1)
    log, connected = run_moteus(moteus_script, tmp_path, drive, moteus_config(**{
        "motor_position.commutation_source": 1}))
    assert connected == [1]
    # every command a velocity in position mode, position NaN, at the output's speed (rotor_to_output_ratio 0.25)
    assert all(math.isnan(c["position"]) and c["velocity"] == SPEED_HZ * 0.25 and c["query"] for c in drive.commands)
    assert drive.stops == [0, drive.rotor.exchanges]  # before the first command (a latched timeout) and at the end
    rows = np.loadtxt(tmp_path / "log" / "moteus_log.csv", delimiter=",", skiprows=1)
    header = (tmp_path / "log" / "moteus_log.csv").read_text().splitlines()[0]
    assert header.split(",") == list(moteus_script.COLUMNS)
    assert rows[0, 0] >= 0 and rows[-1, 0] < 3.0 and len(rows) == len(log.stamps_s) > 1500
    assert np.count_nonzero(np.diff(rows[:, 1]) < 0) == 1 and rows[:, 1].min() >= 0 and rows[:, 1].max() < 2 * np.pi
    mapping = read_mapping(tmp_path / "log" / "mapping.toml")
    assert mapping.motor.pole_pairs == POLE_PAIRS and mapping.motor.slots == SLOTS
    assert mapping.layout.position_unit == "rad" and mapping.layout.current == "measured"
    assert mapping.layout.timer_resolution_s == pytest.approx(np.median(log.round_trips_s), rel=0.01)
    count, torque, cpr = imported(tmp_path, "moteus_log.csv", tmp_path / "log" / "mapping.toml")
    assert count[-1] - count[0] > 1.2 * cpr  # more than a revolution, unwrapped
    theta = 2 * np.pi * count / cpr
    assert np.abs(torque - TORQUE_CONSTANT * i_q_at(theta)).max() < TORQUE_CONSTANT * INTERPOLATION_A


@pytest.mark.parametrize("fail", [RuntimeError("CAN bus off"), asyncio.CancelledError(), KeyboardInterrupt()])
def test_moteus_stops_the_motor_on_every_way_out(moteus_script, tmp_path, fail):
    drive = FakeMoteus(Rotor(seed=4), fail={1500: fail})
    with pytest.raises(type(fail)):
        run_moteus(moteus_script, tmp_path, drive, moteus_config())
    assert drive.stops == [0, 1500]
    rows = (tmp_path / "log" / "moteus_log.csv").read_text().splitlines()
    assert len(rows) > 500 and rows[-1].count(",") == len(moteus_script.COLUMNS) - 1  # the rows before, whole
    assert read_mapping(tmp_path / "log" / "mapping.toml").layout.timer_resolution_s is not None


def test_moteus_fault_or_timeout_ends_the_log_with_one_line(moteus_script, tmp_path):
    drive = FakeMoteus(Rotor(seed=5), mode_at={1000: 11})
    with pytest.raises(moteus_script.DriveError, match=r"^moteus id 1: mode 11 .*fault code 39, after \d+ rows$"):
        run_moteus(moteus_script, tmp_path, drive, moteus_config())
    assert drive.stops == [0, 1001]
    with pytest.raises(moteus_script.DriveError, match="motor.poles = 7: not an even number"):
        run_moteus(moteus_script, tmp_path, FakeMoteus(Rotor(seed=5)), moteus_config(**{"motor.poles": 7}))


def test_moteus_registers_are_the_commutation_sources(moteus_script):
    register = SimpleNamespace(ENCODER_0_POSITION=0x050, ENCODER_0_VELOCITY=0x051, ENCODER_1_POSITION=0x052,
                               ENCODER_1_VELOCITY=0x053, ENCODER_2_POSITION=0x054, ENCODER_2_VELOCITY=0x055,
                               Q_CURRENT=Q_CURRENT, TEMPERATURE=TEMPERATURE, FAULT=FAULT, MODE=MODE)
    mode = SimpleNamespace(FAULT=1, TIMEOUT=11)
    assert moteus_script.Registers.of(register, mode, 2) == moteus_script.Registers(
        0x054, 0x055, Q_CURRENT, TEMPERATURE, FAULT, MODE, HALTED)
    with pytest.raises(moteus_script.DriveError, match="commutation_source = 3: not a source 0, 1 or 2"):
        moteus_script.Registers.of(register, mode, 3)


def test_moteus_main_refuses_bad_options_before_importing_moteus(moteus_script, capsys):
    saved = sys.modules.get("moteus")
    sys.modules["moteus"] = None
    try:
        with pytest.raises(SystemExit) as stop:
            moteus_script.main(["--slots", "0", "--inertia-kgm2", "1e-4", "--torque-constant", "0.1"])
    finally:
        if saved is None:
            del sys.modules["moteus"]
        else:
            sys.modules["moteus"] = saved
    assert stop.value.code == 2 and "--slots" in capsys.readouterr().err


# ---- ODrive


class Part(SimpleNamespace):
    """A node of the fake ODrive's property tree."""


class FakeAxis:
    """An ODrive axis on firmware 0.4 (position in counts, set_vel_setpoint) or 0.5 (pos_estimate in turns,
    pos_estimate_counts, input_vel), its position and I_q read from ``rotor`` (each read is one exchange);
    ``fail`` (exchange -> exception) raises at that read, ``drop_at`` leaves closed loop from that exchange on."""

    def __init__(self, rotor: Rotor, minor: int, fail: dict[int, BaseException] | None = None,
                 drop_at: int | None = None) -> None:
        self.rotor, self.minor, self.fail, self.drop_at = rotor, minor, fail or {}, drop_at
        self.states: list[int] = []
        self.velocity_setpoints: list[float] = []
        self.error = 0
        self.I_measured_report_filter_k = 1.0
        self.motor = Part(error=0x0, current_control=self, config=Part(pole_pairs=POLE_PAIRS, **(
            {"torque_constant": TORQUE_CONSTANT} if minor == 5 else {})))
        self.encoder = (_Encoder04 if minor == 4 else _Encoder05)(self)
        self.controller = Part(error=0, config=Part(control_mode=3, **({"input_mode": 5} if minor == 5 else {})))
        if minor == 4:
            self.controller.set_vel_setpoint = lambda vel, current: self.velocity_setpoints.append(vel)

    def _read(self) -> float:
        if self.rotor.exchanges in self.fail:
            raise self.fail[self.rotor.exchanges]
        return self.rotor.exchange()

    @property
    def Iq_measured(self) -> float:  # noqa: N802  (ODrive's name)
        return float(i_q_at(self._read()))

    @property
    def requested_state(self) -> int:
        return self.states[-1]

    @requested_state.setter
    def requested_state(self, state: int) -> None:
        self.states.append(state)

    @property
    def current_state(self) -> int:
        dropped = self.drop_at is not None and self.rotor.exchanges >= self.drop_at
        self.error = 0x200 if dropped else 0
        return 1 if dropped else self.states[-1]


class _Encoder04:
    """Firmware 0.4's encoder: pos_estimate in counts."""

    def __init__(self, axis: FakeAxis) -> None:
        self.axis, self.error, self.config = axis, 0, Part(cpr=ENCODER_CPR)

    @property
    def pos_estimate(self) -> float:
        return self.axis._read() / (2 * np.pi) * ENCODER_CPR


class _Encoder05(_Encoder04):
    """Firmware 0.5's encoder: pos_estimate in turns, pos_estimate_counts in counts."""

    @property
    def pos_estimate(self) -> float:
        return self.axis._read() / (2 * np.pi)

    @property
    def pos_estimate_counts(self) -> float:
        return self.axis._read() / (2 * np.pi) * ENCODER_CPR


def fake_odrive(axis: FakeAxis, version: tuple[int, int, int]) -> SimpleNamespace:
    return SimpleNamespace(fw_version_major=version[0], fw_version_minor=version[1], fw_version_revision=version[2],
                           axis0=axis)


def run_odrive(script: ModuleType, tmp_path: Path, axis: FakeAxis, version: tuple[int, int, int], *options: str):
    args = script.parse_args(["log", "--slots", str(SLOTS), "--inertia-kgm2", str(INERTIA), "--speed-hz",
                              str(SPEED_HZ), "--duration-s", "3", "--settle-s", "0.5", "--counts-per-rev", "1024",
                              "--out", str(tmp_path / "log"), *options])
    return script.run(fake_odrive(axis, version), args, axis.rotor.clock)


def test_odrive_command_line(odrive_script, capsys):
    args = odrive_script.parse_args(["log", "--slots", "12", "--inertia-kgm2", "2.5e-4"])
    assert (args.axis, args.serial, args.torque_constant, args.speed_hz, args.out) == (0, None, None, 0.5,
                                                                                        Path("odrive-log"))
    assert odrive_script.parse_args(["map"]).out == Path("anticogging_map.npy")
    for bad, option in ((["log", "--slots", "12", "--inertia-kgm2", "0"], "--inertia-kgm2"),
                        (["map", "--axis", "2"], "--axis"), (["log", "--inertia-kgm2", "1"], "--slots"), ([], "")):
        with pytest.raises(SystemExit) as stop:
            odrive_script.parse_args(bad)
        assert stop.value.code == 2 and option in capsys.readouterr().err


@pytest.mark.parametrize("version", [(0, 4, 12), (0, 5, 6)])
def test_odrive_log_imports_as_position_counts_and_q_current(odrive_script, tmp_path, version):
    axis = FakeAxis(Rotor(seed=6), version[1])
    extra = ("--torque-constant", str(TORQUE_CONSTANT)) if version[1] == 4 else ()
    log = run_odrive(odrive_script, tmp_path, axis, version, *extra)
    assert axis.states == [8, 1]  # closed loop, then idle
    assert axis.controller.config.control_mode == 3  # restored
    if version[1] == 4:
        assert axis.velocity_setpoints == [SPEED_HZ * ENCODER_CPR, 0.0]  # counts/s
    else:
        assert axis.controller.input_vel == 0.0 and axis.controller.config.input_mode == 5
    mapping = read_mapping(tmp_path / "log" / "mapping.toml")
    assert mapping.layout.position_counts_per_rev == ENCODER_CPR and mapping.motor.pole_pairs == POLE_PAIRS
    assert mapping.layout.timer_resolution_s == pytest.approx(np.median(log.round_trips_s), rel=0.01)
    count, torque, cpr = imported(tmp_path, "odrive_log.csv", tmp_path / "log" / "mapping.toml")
    assert count[-1] - count[0] > 1.2 * cpr
    # I_q is read one exchange after the position: at most REPLY_GAP_S later, a phase lag of order h x speed x gap
    theta = 2 * np.pi * count / cpr
    lag_a = sum(a * h for h, (a, _) in I_Q_RIPPLE.items()) * LARGEST_STEP_RAD
    assert np.abs(torque - TORQUE_CONSTANT * i_q_at(theta)).max() < TORQUE_CONSTANT * (lag_a + INTERPOLATION_A)


@pytest.mark.parametrize("fail", [RuntimeError("USB disconnected"), KeyboardInterrupt()])
def test_odrive_idles_the_axis_on_every_way_out(odrive_script, tmp_path, fail):
    axis = FakeAxis(Rotor(seed=7), 5, fail={2001: fail})
    with pytest.raises(type(fail)):
        run_odrive(odrive_script, tmp_path, axis, (0, 5, 6))
    assert axis.states == [8, 1] and axis.controller.config.control_mode == 3
    rows = (tmp_path / "log" / "odrive_log.csv").read_text().splitlines()
    assert len(rows) > 300 and rows[-1].count(",") == len(odrive_script.COLUMNS) - 1


def test_odrive_says_when_its_i_q_is_filtered(odrive_script, tmp_path, capsys):
    axis = FakeAxis(Rotor(seed=11), 5)
    run_odrive(odrive_script, tmp_path, axis, (0, 5, 6))
    assert "I_measured_report_filter_k" not in capsys.readouterr().err
    axis = FakeAxis(Rotor(seed=11), 5)
    axis.I_measured_report_filter_k = 0.1
    run_odrive(odrive_script, tmp_path, axis, (0, 5, 6))
    assert "note: motor.current_control.I_measured_report_filter_k is not 1" in capsys.readouterr().err


def test_odrive_axis_leaving_closed_loop_ends_the_log_with_its_errors(odrive_script, tmp_path):
    axis = FakeAxis(Rotor(seed=8), 5, drop_at=1000)
    with pytest.raises(odrive_script.DriveError, match=r"^axis0 left closed-loop control \(axis.error = 0x200, "
                                                       r"motor.error = 0x0, .*\) after \d+ rows$"):
        run_odrive(odrive_script, tmp_path, axis, (0, 5, 6))
    assert axis.states == [8, 1]


@pytest.mark.parametrize("version, message", [((0, 6, 10), "firmware 0.6.10: this script reads"),
                                               ((0, 5, 0), "firmware 0.5.0: this script reads")])
def test_odrive_refuses_firmware_it_does_not_know_before_moving(odrive_script, tmp_path, version, message):
    axis = FakeAxis(Rotor(seed=9), 5)
    with pytest.raises(odrive_script.DriveError, match=message):
        run_odrive(odrive_script, tmp_path, axis, version)
    assert axis.states == []
    with pytest.raises(odrive_script.DriveError, match="firmware 0.4 has no motor.config.torque_constant"):
        run_odrive(odrive_script, tmp_path, FakeAxis(Rotor(seed=9), 4), (0, 4, 12))


def test_odrive_map_is_the_holding_current_per_entry(odrive_script, tmp_path):
    torque_nm = 0.01 * np.sin(84 * 2 * np.pi * np.arange(3600) / 3600)
    axis = FakeAxis(Rotor(seed=10), 5)
    axis.controller.anticogging_valid = True
    axis.controller.get_anticogging_value = lambda k: float(torque_nm[k]) if 0 <= k < 3600 else 0.0
    args = odrive_script.parse_args(["map", "--out", str(tmp_path / "map.npy")])
    current_a = odrive_script.read_map(fake_odrive(axis, (0, 5, 6)), args)
    assert current_a.shape == (3600,) and np.allclose(current_a, torque_nm / TORQUE_CONSTANT)
    with pytest.raises(odrive_script.DriveError, match=r"firmware 0.5.5 does not give its anticogging map"):
        odrive_script.read_map(fake_odrive(axis, (0, 5, 5)), args)
    axis.controller.anticogging_valid = False
    with pytest.raises(odrive_script.DriveError, match="anticogging_valid is false"):
        odrive_script.read_map(fake_odrive(axis, (0, 5, 6)), args)


def test_the_mappings_state_what_bench_format_reads(moteus_script, odrive_script):
    """The mapping text without rows: no timer_resolution_s, k_1 = 2 K_t / 3 (K_q = 3/2 k_1 = K_t)."""
    motor = moteus_script.Motor(POLE_PAIRS, SLOTS, 4096, INERTIA, TORQUE_CONSTANT)
    for text in (moteus_script.mapping_text(motor, []), odrive_script.mapping_text(motor, ENCODER_CPR, [])):
        data = tomllib.loads(text)
        assert "timer_resolution_s" not in data["log"]
        assert 1.5 * data["bench"]["backemf"]["amplitudes_nm_per_a"][0] == pytest.approx(TORQUE_CONSTANT)
    assert "timer_resolution_s = 0.001" in moteus_script.mapping_text(motor, [0.3, 0.004])  # within the bound
