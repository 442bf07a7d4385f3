"""A moteus drive as a `DriveBackend` (docs/moteus.md), on mjbots' own library: its `Controller`, `Stream` (the
text console) and transports, or this package's emulated moteus.

A trial stops the drive, uploads its table into the drive's RAM (``conf set``; flash only through `store_table`
with ``--write-config``), commands position mode with position NaN at the trial's velocity, and polls at
[backends.moteus] query_rate_hz (each poll renews the command and its watchdog) until the recorded seconds are
over. Every path out of a trial (its end, an error, a fault the drive reports, Ctrl-C, a lost connection) sends a
stop; a stop that cannot be confirmed is said so, and the drive's watchdog stops it anyway.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Awaitable, Callable

import moteus
import numpy as np
from moteus import multiplex as mp
from moteus.protocol import Mode, Register

from ilcpmac.backends.drive import DriveLimits, DriveTrial
from ilcpmac.backends.moteus.emulated import EmulatedMoteusDevice
from ilcpmac.backends.moteus.settings import SECTION, MoteusSettings, parse_settings
from ilcpmac.bench.rolling import RollingData
from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import BackendError, ConfigError, IlcpmacError, SafetyError
from ilcpmac.core.records import (
    CURRENTS_FROM_I_Q,
    BenchDescription,
    DriveTrialRequest,
    MotorInfo,
    SensorCalibration,
    TrialData,
    TrialRequest,
)
from ilcpmac.export import MOTEUS_TABLE_SIZE
from ilcpmac.model.tables import backemf_table
from ilcpmac.sim.moteus_drive import EmulatedDrive

if TYPE_CHECKING:
    from ilcpmac.backends.registry import BackendSetup

__all__ = ["FAULT_NAMES", "MoteusBackend", "fault_text", "moteus_description", "unwrapped_revolutions"]

log = logging.getLogger(__name__)

#: fw/error.h: the codes a moteus reports in its FAULT register (96 and above: a limit active, not a fault)
FAULT_NAMES = {
    1: "kDmaStreamTransferError", 2: "kDmaStreamFifoError", 3: "kUartOverrunError", 4: "kUartFramingError",
    5: "kUartNoiseError", 6: "kUartBufferOverrunError", 7: "kUartParityError", 32: "kCalibrationFault",
    33: "kMotorDriverFault", 34: "kOverVoltage", 35: "kEncoderFault", 36: "kMotorNotConfigured",
    37: "kPwmCycleOverrun", 38: "kOverTemperature", 39: "kStartOutsideLimit", 40: "kUnderVoltage",
    41: "kConfigChanged", 42: "kThetaInvalid", 43: "kPositionInvalid", 44: "kDriverEnableFault",
    45: "kStopPositionDeprecated", 46: "kTimingViolation", 47: "kBemfFeedforwardNoAccelLimit", 48: "kInvalidLimits",
    49: "kPositionControlError", 50: "kVelocityControlError", 96: "kLimitMaxVelocity", 97: "kLimitMaxPower",
    98: "kLimitMaxVoltage", 99: "kLimitMaxCurrent", 100: "kLimitFetTemperature", 101: "kLimitMotorTemperature",
    102: "kLimitMaxTorque", 103: "kLimitPositionBounds", 104: "kLimitFluxBraking", 105: "kLimitFieldWeakening",
}
#: the drive's own limits, by their config names
LIMIT_NAMES = ("servo.max_current_A", "servo.max_velocity", "servo.fault_temperature",
               "servo.motor_fault_temperature")
OUTPUT_RATIO_NAME = "motor_position.rotor_to_output_ratio"
#: the current loop's bandwidth, Hz (firmware of 2024 on; older ones: unknown)
CURRENT_BANDWIDTH_NAME = "servo.pid_dq_hz"
TABLE_SCALE_NAME = "motor.cogging_dq_scale"
TABLE_ENTRY_NAME = "motor.cogging_dq_comp.{}"
#: the real seconds the emulated transport's reply is waited for at most (a guard against a hang: it answers
#: within the call)
EMULATED_TIMEOUT_S = 10.0
#: tries of a stop command before the backend gives up on it (the drive's watchdog stops it then)
STOP_TRIES = 3
#: the part of a trial's settling time over which its velocity command ramps up from 0
RAMP_FRACTION = 0.5
#: seconds the console is drained after ``tel stop`` (the firmware may be streaming telemetry)
TEL_STOP_FLUSH_S = 0.2


def fault_text(code: int) -> str:
    """A FAULT register's value as moteus names it: ``"kOverTemperature (38)"``."""
    return f"{FAULT_NAMES.get(code, 'an unknown code')} ({code})"


def _query_resolution() -> moteus.QueryResolution:
    """What a poll reads: the mode and fault, the output's velocity, the q current, both temperatures, and the
    commutation encoder's position and velocity (the table is indexed by it)."""
    qr = moteus.QueryResolution()
    qr.mode, qr.fault = mp.INT8, mp.INT8
    qr.position, qr.torque, qr.voltage = mp.IGNORE, mp.IGNORE, mp.IGNORE
    qr.velocity, qr.q_current = mp.F32, mp.F32
    qr.temperature, qr.motor_temperature = mp.F32, mp.F32
    qr._extra = {Register.ENCODER_0_POSITION: mp.F32, Register.ENCODER_0_VELOCITY: mp.F32}
    return qr


class MoteusBackend:
    """Runs drive trials on one moteus controller (`DriveBackend`); grid trials, which need a load, it refuses.

    Not thread-safe: one trial at a time. It owns one asyncio event loop; a Ctrl-C (or any exception) that
    escapes it mid-trial cancels the trial, whose stop then still goes out, before it propagates.

    Parameters
    ----------
    settings : MoteusSettings
    description : BenchDescription
    device : moteus TransportDevice, or None
        The emulated moteus (whose ``clock`` and ``sleep`` are virtual), or None with ``transport``.
    transport : moteus.Transport, optional
        A real transport (its time is the host's); default: one on ``device``.
    write_config : bool
        The user's word that `store_table` may write the drive's flash.
    loop : asyncio event loop, optional
        The loop ``transport`` was built on.
    """

    max_parallel_trials = 1

    def __init__(self, settings: MoteusSettings, description: BenchDescription, device: Any = None, *,
                 transport: Any = None, write_config: bool = False,
                 loop: asyncio.AbstractEventLoop | None = None) -> None:
        self.settings = settings
        self.description = description
        self.device = device
        self.write_config = write_config
        self._loop = loop if loop is not None else asyncio.new_event_loop()
        self.transport = transport if transport is not None else moteus.Transport(device)
        self.controller = moteus.Controller(id=settings.id, transport=self.transport,
                                            query_resolution=_query_resolution())
        self.stream = moteus.Stream(self.controller)
        self._clock: Callable[[], float] = getattr(device, "clock", time.monotonic)
        self._sleep: Callable[[float], Awaitable[None]] = getattr(device, "sleep", asyncio.sleep)
        #: the real seconds a poll's reply is waited for: the setting on a real transport; on the emulated one,
        #: which answers (or loses a reply) within the call on its own clock, only a guard against a hang, so that
        #: how loaded this machine is never loses a poll there
        self._poll_timeout_s = settings.poll_timeout_s if device is None else EMULATED_TIMEOUT_S
        self._limits: DriveLimits | None = None
        self._ratio: float | None = None
        self._quiet = False
        #: the table the drive holds in RAM, as this backend knows it: (entries, scale) or None (not read yet)
        self._held: tuple[np.ndarray, float] | None = None

    @classmethod
    def from_setup(cls, setup: BackendSetup) -> MoteusBackend:
        """A moteus controller through mjbots' moteus library, or the emulated moteus ([backends.moteus]).

        Its options are checked (`ConfigError`) before anything connects; ``--address`` may only name the
        fdcanusb's serial port or the socketcan interface."""
        config = setup.config
        settings = parse_settings(setup.options, str(config.path))
        settings = _with_address(settings, setup.address)
        description = moteus_description(config, settings.query_rate_hz)
        if settings.transport == "emulated":
            drive = EmulatedDrive(config.simulated_model(), settings.drive, settings.link.seed)
            device = EmulatedMoteusDevice(drive, can_id=settings.id, round_trip_s=settings.link.round_trip_s,
                                          jitter_s=settings.link.jitter_s, seed=settings.link.seed,
                                          reply_timeout_s=settings.poll_timeout_s)
            return cls(settings, description, device, write_config=setup.write_config)
        loop = asyncio.new_event_loop()
        try:
            transport = loop.run_until_complete(_real_transport(settings))
        except IlcpmacError:
            loop.close()
            raise
        except Exception as e:  # the library's own errors (no adapter found, a port that will not open)
            loop.close()
            raise BackendError(f"moteus {settings.transport}: cannot open the transport ({type(e).__name__}: {e})") \
                from None
        return cls(settings, description, transport=transport, write_config=setup.write_config, loop=loop)

    # ------------------------------------------------------------------ the Backend protocol

    def describe(self) -> BenchDescription:
        return self.description

    def run_trial(self, request: TrialRequest) -> TrialData:
        raise BackendError("the moteus backend runs no grid trial: a grid trial needs a load and a torque sensor; "
                           "the moteus backend runs the drive campaign ([drive], docs/moteus.md)")

    def close(self) -> None:
        """Stop the drive and release the transport and the event loop."""
        try:
            problem = self._run(self._stop())
            if problem is not None:
                log.warning("moteus: at close, %s", problem)
        finally:
            self.transport.close()
            self._loop.close()

    # ------------------------------------------------------------------ the DriveBackend protocol

    def drive_limits(self) -> DriveLimits:
        """servo.max_current_A, servo.max_velocity (the output's, as the rotor's speed) and the lower of
        servo.fault_temperature and servo.motor_fault_temperature, read with ``conf get`` (NaN, infinite or absent:
        unbounded); and the current loop's bandwidth servo.pid_dq_hz (absent: None)."""
        return self._run(self._drive_limits())

    def run_drive_trial(self, request: DriveTrialRequest) -> DriveTrial:
        return self._run(self._trial(request))

    def store_table(self, request: DriveTrialRequest) -> None:
        if not self.write_config:
            raise SafetyError("--write-config not given: nothing written to the drive's flash")
        self._run(self._store(request))

    # ------------------------------------------------------------------ on the event loop

    def _run(self, coroutine):
        task = self._loop.create_task(coroutine)
        try:
            return self._loop.run_until_complete(task)
        except IlcpmacError:
            raise
        except Exception as e:  # the library's and the transport's errors, as one line
            raise BackendError(f"moteus {self.settings.transport}: {type(e).__name__}: {e}") from None
        except BaseException:  # Ctrl-C, raised wherever the loop was (a transport's task, a select)
            if not task.done():
                task.cancel()  # the trial's own except path stops the drive
                with contextlib.suppress(BaseException):
                    self._loop.run_until_complete(task)
            raise

    async def _drive_limits(self) -> DriveLimits:
        if self._limits is None:
            current, velocity, fet, motor = [await self._config_value(name) for name in LIMIT_NAMES]
            bandwidth = await self._config_value(CURRENT_BANDWIDTH_NAME)
            self._limits = DriveLimits(current, velocity / abs(await self._output_ratio()), min(fet, motor),
                                       bandwidth if math.isfinite(bandwidth) and bandwidth > 0 else None)
        return self._limits

    async def _trial(self, request: DriveTrialRequest) -> DriveTrial:
        limits = await self._drive_limits()
        if abs(request.speed_hz) > limits.max_speed_hz:
            raise SafetyError(f"drive trial at {request.speed_hz:g} Hz refused: beyond the drive's servo.max_velocity "
                              f"({limits.max_speed_hz:g} Hz of the rotor)")
        peak_a = float(np.max(np.abs(request.table_current_a())))
        if peak_a > limits.max_current_a:
            raise SafetyError(f"drive trial refused: its table asks {peak_a:.4g} A, beyond the drive's "
                              f"servo.max_current_A {limits.max_current_a:g} A")
        await self._prepare()
        await self._upload(request)
        try:
            trial = await self._roll(request)
        except BaseException as e:
            problem = await self._stop()
            if problem is not None:
                if isinstance(e, Exception):
                    raise BackendError(f"{e}; then {problem}") from None
                log.error("moteus: %s", problem)
            raise
        problem = await self._stop()
        if problem is not None:
            raise BackendError(f"after the trial, {problem}")
        return trial

    async def _store(self, request: DriveTrialRequest) -> None:
        await self._prepare()
        await self._upload(request)
        await self._console("conf write")

    async def _prepare(self) -> None:
        """Telemetry off (once), and the drive stopped (which also clears a fault or a watchdog timeout)."""
        if not self._quiet:
            if isinstance(self.device, EmulatedMoteusDevice):
                # it sends no telemetry: its answer alone is read. Flushing for TEL_STOP_FLUSH_S of real time read
                # as often as the host's speed allowed, each read advancing its clock, and made two runs differ
                await self._console("tel stop")
            else:
                await self.stream.write_message(b"tel stop")
                await self.stream.flush_read(timeout=TEL_STOP_FLUSH_S)  # what telemetry was under way
            self._quiet = True
        problem = await self._stop()
        if problem is not None:
            raise BackendError(f"before the trial, {problem}")

    async def _upload(self, request: DriveTrialRequest) -> None:
        """``request``'s table into the drive's RAM: its scale, then each entry that differs from what it holds."""
        values = np.asarray(request.table_values, np.int64)
        if values.shape != (MOTEUS_TABLE_SIZE,):
            raise BackendError(f"a moteus table has {MOTEUS_TABLE_SIZE} entries, the request has {values.size}")
        if self._held is None:
            held = [await self._config_value(TABLE_ENTRY_NAME.format(k)) for k in range(MOTEUS_TABLE_SIZE)]
            self._held = (np.asarray(held), await self._config_value(TABLE_SCALE_NAME))
        entries, scale = self._held
        self._held = None  # unknown while a command is out (it may or may not act)
        if request.table_scale_a != scale:
            await self._console(f"conf set {TABLE_SCALE_NAME} {request.table_scale_a!r}")
        for k in np.flatnonzero(values != entries):
            await self._console(f"conf set {TABLE_ENTRY_NAME.format(k)} {values[k]}")
            entries[k] = values[k]
        self._held = (entries, request.table_scale_a)

    async def _roll(self, request: DriveTrialRequest) -> DriveTrial:
        """Command and poll: ``settle_s`` unrecorded (the velocity command ramped from the rotor's over its first
        `RAMP_FRACTION`, so the loop's torque stays small), then ``seconds`` recorded."""
        s = self.settings
        ratio = await self._output_ratio()
        target_hz = request.speed_hz * ratio
        # the ramp starts at the rotor's speed as the drive reports it, but never commands more than the speed the
        # guard checked: a reply's velocity (NaN, a glitch) is not a checked value, and a rotor still coasting
        # faster from before is left to coast down, stopped, within the settling time
        measured_hz = await self._coasted_below(abs(target_hz), self._clock() + request.settle_s)
        initial_hz = min(max(measured_hz, -abs(target_hz)), abs(target_hz))
        drive = self.device.drive if isinstance(self.device, EmulatedMoteusDevice) else None
        period_s = 1.0 / s.query_rate_hz
        start_s = self._clock()
        record_s, end_s = start_s + request.settle_s, start_s + request.duration_s
        recording = False
        polls = lost = unanswered = 0
        stamps: list[float] = []
        revolutions: list[float] = []
        speeds: list[float] = []
        currents: list[float] = []
        hottest = -math.inf
        next_s = start_s
        ramp_s = RAMP_FRACTION * request.settle_s
        while (now := self._clock()) < end_s:
            if not recording and now >= record_s:
                recording = True
                if drive is not None:
                    drive.truth_reset()
            sent_s = self._clock()
            ramped = min(1.0, (now - start_s) / ramp_s) if ramp_s > 0 else 1.0
            reply = await self._poll(initial_hz + (target_hz - initial_hz) * ramped)
            stamp_s = (sent_s + self._clock()) / 2
            polls += recording
            if reply is None:
                lost += recording
                unanswered += 1
                if unanswered > s.max_lost_polls:
                    raise BackendError(f"moteus id {s.id}: connection lost: {unanswered} polls in a row unanswered "
                                       f"(more than [{SECTION}] max_lost_polls {s.max_lost_polls})")
            else:
                unanswered = 0
                values = reply.values
                _check_reply(values, s.id)
                hottest = max(hottest, *(t for t in (values.get(Register.TEMPERATURE, math.nan),
                                                     values.get(Register.MOTOR_TEMPERATURE, math.nan))
                                         if math.isfinite(t)), -math.inf)
                if recording:
                    stamps.append(stamp_s - record_s)
                    revolutions.append(values[Register.ENCODER_0_POSITION])
                    speeds.append(values[Register.ENCODER_0_VELOCITY])
                    currents.append(values[Register.Q_CURRENT])
            next_s += period_s
            wait_s = next_s - self._clock()
            if wait_s > 0:
                await self._sleep(wait_s)
            else:
                next_s = self._clock()  # late: the next poll at once, never a burst to catch up
        if len(stamps) < 2:
            raise BackendError(f"moteus id {s.id}: fewer than 2 polls answered while recording ({polls} sent)")
        cpr = self.description.motor.counts_per_rev
        time_s = np.asarray(stamps)
        position = unwrapped_revolutions(np.asarray(revolutions), np.asarray(speeds), time_s) * cpr
        data = RollingData(time_s=time_s, position_counts=position, segment=np.ones(time_s.size, np.int64),
                           i_q_a=np.asarray(currents))
        truth = drive.truth(cpr) if drive is not None else (None, None)
        return DriveTrial(request=request, data=data, polls=polls, lost=lost,
                          max_temperature_c=hottest if math.isfinite(hottest) else math.nan,
                          true_residual_nm=truth[0], true_position_torque_nm=truth[1])

    async def _coasted_below(self, limit_hz: float, deadline_s: float) -> float:
        """The rotor's speed (0 where the drive does not say), once at most ``limit_hz`` in magnitude: stopped and
        polled until then; `BackendError` where it still turns faster at ``deadline_s``."""
        while True:
            reply = await self._timed(self.controller.set_stop(query=True))
            measured_hz = float(reply.values.get(Register.VELOCITY, 0.0)) if reply is not None else 0.0
            measured_hz = measured_hz if math.isfinite(measured_hz) else 0.0
            if abs(measured_hz) <= limit_hz:
                return measured_hz
            if self._clock() >= deadline_s:
                raise BackendError(f"moteus id {self.settings.id}: the rotor still turns at {measured_hz:.3g} Hz, "
                                   f"faster than the trial's {limit_hz:g} Hz, after its settling time: let it stop "
                                   "first (a longer [drive] settle_s)")
            await self._sleep(1.0 / self.settings.query_rate_hz)

    async def _poll(self, velocity_hz: float):
        """One position-mode command (position NaN, the output's ``velocity_hz``, the watchdog) with a query; None
        if unanswered."""
        return await self._timed(self.controller.set_position(
            position=math.nan, velocity=velocity_hz, watchdog_timeout=self.settings.watchdog_timeout_s, query=True))

    async def _timed(self, command: Awaitable[Any]) -> Any:
        """``command``'s reply, or None without one within poll_timeout_s."""
        try:
            async with asyncio.timeout(self._poll_timeout_s):
                return await command
        except TimeoutError:
            return None

    async def _output_ratio(self) -> float:
        """Output revolutions per rotor revolution (motor_position.rotor_to_output_ratio; 1 where the drive has
        none): a command's velocity is the output's."""
        if self._ratio is None:
            ratio = await self._config_value(OUTPUT_RATIO_NAME)
            self._ratio = ratio if math.isfinite(ratio) and ratio != 0 else 1.0
        return self._ratio

    async def _stop(self) -> str | None:
        """A stop, confirmed by the drive's reply (mode stopped, or fault), tried `STOP_TRIES` times; None once
        confirmed, else what went wrong (the drive's watchdog stops it anyway)."""
        why = "no reply"
        for _ in range(STOP_TRIES):
            try:
                async with asyncio.timeout(self._poll_timeout_s):
                    reply = await self.controller.set_stop(query=True)
            except TimeoutError:
                continue
            except Exception as e:  # the transport failing: tried again, then reported
                why = f"{type(e).__name__}: {e}"
                continue
            if reply is not None and reply.values.get(Register.MODE) in (Mode.STOPPED, Mode.FAULT):
                return None  # a fault that persists (still too hot) drives no current either
            if reply is not None:
                why = f"the drive stayed in mode {reply.values.get(Register.MODE)}"
        return (f"the stop command was not confirmed in {STOP_TRIES} tries ({why}): the drive's watchdog stops it "
                f"after {self.settings.watchdog_timeout_s:g} s without a command")

    async def _console(self, line: str, value: bool = False) -> str:
        """One console command's answer; ``ERR`` or no answer within console_timeout_s raises `BackendError`."""
        try:
            async with asyncio.timeout(self.settings.console_timeout_s):
                answer = await self.stream.command(line.encode("latin1"), allow_any_response=value)
        except TimeoutError:
            raise BackendError(f"moteus id {self.settings.id}: no answer to {line!r} within "
                               f"[{SECTION}] console_timeout_s {self.settings.console_timeout_s:g} s") from None
        except moteus.CommandError as e:
            raise BackendError(f"moteus id {self.settings.id}: {line!r} answered {e.message}") from None
        return answer.decode("latin1").strip()

    async def _config_value(self, name: str) -> float:
        """``conf get NAME`` as a number: NaN or absent (ERR) mean unbounded (inf)."""
        answer = await self._console(f"conf get {name}", value=True)
        if answer.startswith("ERR"):
            return math.inf
        try:
            value = float(answer)
        except ValueError:
            raise BackendError(f"moteus id {self.settings.id}: conf get {name} answered {answer[:60]!r}, "
                               "not a number") from None
        return math.inf if math.isnan(value) else value


def _check_reply(values: dict, can_id: int) -> None:
    """Raise `BackendError` naming the fault of a reply in mode FAULT or TIMEOUT, or with a fault code set."""
    mode, fault = values.get(Register.MODE), values.get(Register.FAULT, 0)
    if mode == Mode.TIMEOUT:
        raise BackendError(f"moteus id {can_id}: the drive's watchdog timed out (mode TIMEOUT): the trial stopped")
    if mode == Mode.FAULT or fault:
        kind = "limit" if fault >= 96 else "fault"
        raise BackendError(f"moteus id {can_id} reported the {kind} {fault_text(int(fault))} in mode "
                           f"{mode}: the trial stopped")


def unwrapped_revolutions(position_rev: np.ndarray, speed_hz: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """A commutation encoder's readings in [0, 1) as one continuous position, rev: each step the whole number of
    turns that makes it nearest to what the reported speeds predict (right across lost polls)."""
    step = np.diff(position_rev)
    expected = 0.5 * (speed_hz[1:] + speed_hz[:-1]) * np.diff(time_s)
    step -= np.rint(step - expected)
    return position_rev[0] + np.concatenate([[0.0], np.cumsum(step)])


def _with_address(settings: MoteusSettings, address: str | None) -> MoteusSettings:
    """``--address`` as the fdcanusb's port or the socketcan interface; anything else refused."""
    if address is None:
        return settings
    if settings.transport not in ("fdcanusb", "socketcan"):
        raise ConfigError(f"--address {address}: the moteus backend's {settings.transport} transport takes no "
                          f"address (an fdcanusb's port or a socketcan interface goes in [{SECTION}] device)")
    if settings.device is not None and settings.device != address:
        raise ConfigError(f"--address {address} and [{SECTION}] device {settings.device!r} disagree: give one")
    return replace(settings, device=address)


def moteus_description(config: CampaignConfig, query_rate_hz: float) -> BenchDescription:
    """The motor as [bench] (and its back-EMF as [bench.backemf] or the simulated drive's) states it: no torque
    sensor, the q current polled at ``query_rate_hz``."""
    bench = config.bench
    backemf = config.model.backemf if config.model is not None else bench.backemf
    if backemf is None or bench.inertia_kgm2 is None:
        raise ConfigError(f"{config.path}: the moteus backend needs [bench] inertia_kgm2 and [bench.backemf] "
                          "(the motor's back-EMF, for the torque of the q current)")
    motor = MotorInfo(bench.pole_pairs, bench.slots, bench.counts_per_rev, bench.inertia_kgm2, torque_sensor=False,
                      currents=CURRENTS_FROM_I_Q, inertia_uncertainty=bench.inertia_uncertainty,
                      log_rate_hz=query_rate_hz)
    calibration = (bench.calibration.calibration() if bench.calibration is not None
                   else SensorCalibration(np.ones(3), np.zeros(3), 1.0))  # the drive's own, in amperes
    return BenchDescription(motor=motor, backemf_nm_per_a=backemf_table(motor, backemf, bench.counts_per_rev),
                            calibration=calibration, limits=config.limits.bench_limits())


async def _real_transport(settings: MoteusSettings) -> moteus.Transport:
    """The moteus library's transport for ``settings`` (built on the backend's loop)."""
    from moteus.transport_factory import get_singleton_transport, get_transport_factories, make_transport_args

    names = {factory.name for factory in get_transport_factories()}
    if settings.transport == "pi3hat" and "pi3hat" not in names:
        raise ConfigError(f"[{SECTION}] transport pi3hat: the moteus_pi3hat package is not installed "
                          "(pip install moteus-pi3hat, on the Raspberry Pi)")
    args = {"fdcanusb": ["--force-transport", "fdcanusb"] + (["--fdcanusb", settings.device] if settings.device
                                                               else []),
            "socketcan": ["--force-transport", "pythoncan", "--can-iface", "socketcan", "--can-chan",
                          settings.device or "can0"],
            "pi3hat": ["--force-transport", "pi3hat"]}[settings.transport]
    parser = argparse.ArgumentParser(add_help=False)
    make_transport_args(parser)
    return get_singleton_transport(parser.parse_args(args))
