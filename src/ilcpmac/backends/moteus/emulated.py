"""An emulated moteus on the moteus library's own transport interface (docs/moteus.md): `EmulatedMoteusDevice`, a
`moteus.TransportDevice` that decodes the library's frames (its multiplex parser) and answers as the firmware does
(fw/moteus_controller.cc) from an `ilcpmac.sim.moteus_drive.EmulatedDrive`, on virtual time.

Every transaction advances the drive by one round trip (half before its frames act, half after: the replies show
the drive mid-way); `clock` gives the virtual seconds and `sleep` advances the drive without real waiting, which the
backend uses in place of ``time.monotonic`` and ``asyncio.sleep``. Frames it cannot parse, addressed elsewhere, or
naming registers it does not hold are dropped or answered with the protocol's error subframes, never raised.
"""

from __future__ import annotations

import io
import math
import struct
from typing import Callable

import numpy as np
from moteus import multiplex as mp
from moteus.protocol import Mode, Register, scale_register
from moteus.transport_device import Frame, TransportDevice

from ilcpmac.core.errors import SimulationError
from ilcpmac.sim.moteus_drive import DriveStatus, EmulatedDrive

__all__ = ["CONSOLE_CHANNEL", "EmulatedMoteusDevice"]

#: the diagnostic channel that carries the text console
CONSOLE_CHANNEL = 1
#: fw multiplex error codes
_UNKNOWN_REGISTER, _NOT_WRITEABLE = 1, 2
#: the longest console line, and console output held unread, bytes (the firmware's buffers are as small)
_MAX_LINE = 256
_MAX_OUTPUT = 4096
#: a CAN-FD frame's payload, and a diagnostic reply's data within it (1 type + 1 channel + 1 size), bytes
_MAX_FRAME = 64
_MAX_STREAM_DATA = _MAX_FRAME - 3
#: registers a query reads: the drive's status field each one shows
_STATUS_REGISTERS: dict[int, Callable[[DriveStatus], float]] = {
    Register.MODE: lambda s: s.mode,
    Register.POSITION: lambda s: s.position_rev,
    Register.VELOCITY: lambda s: s.velocity_hz,
    Register.TORQUE: lambda s: s.torque_nm,
    Register.Q_CURRENT: lambda s: s.q_current_a,
    Register.D_CURRENT: lambda s: s.d_current_a,
    Register.MOTOR_TEMPERATURE: lambda s: s.motor_temperature_c,
    Register.VOLTAGE: lambda s: s.voltage_v,
    Register.TEMPERATURE: lambda s: s.temperature_c,
    Register.FAULT: lambda s: s.fault,
    Register.ENCODER_0_POSITION: lambda s: s.encoder0_position_rev,
    Register.ENCODER_0_VELOCITY: lambda s: s.encoder0_velocity_hz,
}
#: the command registers of a position-mode command the emulated drive obeys: its keyword and default
_POSITION_COMMAND = {
    Register.COMMAND_POSITION: ("position_rev", math.nan),
    Register.COMMAND_VELOCITY: ("velocity_hz", 0.0),
    Register.COMMAND_FEEDFORWARD_TORQUE: ("feedforward_nm", 0.0),
    Register.COMMAND_POSITION_MAX_TORQUE: ("max_torque_nm", math.inf),
    Register.COMMAND_TIMEOUT: ("watchdog_timeout_s", math.nan),
}
_READ_ONLY = set(_STATUS_REGISTERS) | {Register.MILLISECOND_COUNTER}


class EmulatedMoteusDevice(TransportDevice):
    """A moteus controller, emulated, as a `moteus.Transport` device.

    Parameters
    ----------
    drive : EmulatedDrive
    can_id : int
        Its CAN id (id.id); frames for other ids go unanswered.
    round_trip_s, jitter_s : float
        One transaction's round trip, and its random extra (uniform in [0, jitter_s]), virtual s.
    seed : int
        Seed of the jitter.
    reply_timeout_s : float
        Virtual seconds a transaction takes whose reply is lost (what a host waits before it gives up).
    on_transaction : callable, optional
        ``on_transaction(n)`` is called before transaction ``n`` (0, 1, ...) acts; tests raise there (an
        exception or ``KeyboardInterrupt`` inside the transport) or send a signal.
    cut_at : int, optional
        From transaction ``cut_at`` on, nothing passes either way (a pulled cable): commands are lost too.
    mute_at : int, optional
        From transaction ``mute_at`` on, the drive obeys its commands but its replies are lost.
    """

    def __init__(self, drive: EmulatedDrive, *, can_id: int = 1, round_trip_s: float = 2e-4, jitter_s: float = 5e-5,
                 seed: int = 0, reply_timeout_s: float = 0.01, on_transaction: Callable[[int], None] | None = None,
                 cut_at: int | None = None, mute_at: int | None = None) -> None:
        super().__init__()
        self.drive = drive
        self.can_id = can_id
        self.round_trip_s, self.jitter_s, self.reply_timeout_s = round_trip_s, jitter_s, reply_timeout_s
        self.on_transaction, self.cut_at, self.mute_at = on_transaction, cut_at, mute_at
        self.transactions = 0
        self._rng = np.random.default_rng(seed)
        self._console_in = b""
        self._console_out = b""

    def empty_bus_tx_safe(self) -> bool:
        return True

    def clock(self) -> float:
        """Virtual seconds since the drive's power-up."""
        return self.drive.time_s

    async def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of virtual time pass (the drive runs them), at once."""
        if seconds > 0:
            self.drive.advance(seconds)

    async def send_frame(self, frame: Frame) -> None:
        """A frame sent without a reply wanted (`moteus.Transport.write`)."""
        await self.transaction([TransportDevice.Request(frame=frame)])

    async def transaction(self, requests: list[TransportDevice.Request], **kwargs) -> None:
        """Deliver ``requests``' frames to the drive and store its replies in their ``responses``."""
        n = self.transactions
        self.transactions += 1
        if self.on_transaction is not None:
            self.on_transaction(n)
        lost = self.cut_at is not None and n >= self.cut_at
        muted = lost or (self.mute_at is not None and n >= self.mute_at)
        round_trip_s = self.round_trip_s + self.jitter_s * float(self._rng.random())
        self.drive.advance(round_trip_s / 2)
        answers = [] if lost else [(request, self._receive(request.frame)) for request in requests
                                   if request.frame is not None]
        self.drive.advance(round_trip_s / 2)
        waited = False
        for request, reply in answers:
            if reply is None or request.frame_filter is None:
                continue
            if muted or not request.frame_filter(reply):
                waited = True
                continue
            request.responses.append(reply)
        if lost and any(request.frame_filter is not None for request in requests):
            waited = True
        if waited:
            self.drive.advance(self.reply_timeout_s)

    # ------------------------------------------------------------------ one frame

    def _receive(self, frame: Frame) -> Frame | None:
        """The drive's reply to ``frame`` (None: no reply), after its writes acted."""
        arbitration_id = int(frame.arbitration_id)
        destination, source = arbitration_id & 0x7F, (arbitration_id >> 8) & 0x7F
        prefix = (arbitration_id >> 16) & 0x1FFF
        if prefix != 0 or destination not in (self.can_id, 0x7F):
            return None
        reply = io.BytesIO()
        writer = mp.WriteFrame(reply)
        command: dict[int, float] = {}
        mode: int | None = None
        try:
            subframes = list(mp.parse_frame(bytes(frame.data)))
        except (RuntimeError, struct.error, ValueError, IndexError):  # truncated or garbled: discarded whole
            return None
        for sub in subframes:
            if isinstance(sub, mp.RegisterSubframe) and sub.type == mp.SubframeType.WRITE:
                value = scale_register(sub.register, sub.resolution, sub.value)
                if sub.register == Register.MODE:
                    mode = int(value) if math.isfinite(value) else -1
                    command = {}
                elif sub.register in _POSITION_COMMAND:
                    command[sub.register] = float(value)
                else:
                    _error(writer, mp.WRITE_ERROR, sub.register,
                           _NOT_WRITEABLE if sub.register in _READ_ONLY else _UNKNOWN_REGISTER)
            elif isinstance(sub, mp.RegisterSubframe) and sub.type == mp.SubframeType.READ:
                continue
            elif isinstance(sub, mp.StreamSubframe) and sub.channel == CONSOLE_CHANNEL:
                if sub.type == mp.SubframeType.STREAM_CLIENT_TO_SERVER:
                    self._console(sub.data)
        if mode is not None:
            self._command(mode, command, writer)
        status = self.drive.status()
        for sub in subframes:
            if isinstance(sub, mp.RegisterSubframe) and sub.type == mp.SubframeType.READ:
                self._read(sub, status, writer)
            elif (isinstance(sub, mp.StreamSubframe) and sub.channel == CONSOLE_CHANNEL
                  and sub.type == mp.SubframeType.STREAM_CLIENT_POLL_SERVER):
                size = min(sub.data[0], _MAX_STREAM_DATA, _MAX_FRAME - writer.size() - 3)
                if size < 0:
                    continue
                data, self._console_out = self._console_out[:size], self._console_out[size:]
                writer.write_int8(mp.STREAM_SERVER_DATA)
                writer.write_varuint(CONSOLE_CHANNEL)
                writer.write_varuint(len(data))
                reply.write(data)
        if not arbitration_id & 0x8000 or not reply.getvalue():
            return None
        data = reply.getvalue()[:_MAX_FRAME]
        size = self._round_up_dlc(len(data))
        return Frame(arbitration_id=(self.can_id << 8) | source, data=data + b"\x50" * (size - len(data)), dlc=size,
                     is_extended_id=True, is_fd=True, bitrate_switch=True, channel=self)

    def _command(self, mode: int, command: dict[int, float], writer: mp.WriteFrame) -> None:
        if mode == Mode.POSITION:
            kwargs = {name: command.get(register, default) for register, (name, default) in _POSITION_COMMAND.items()}
            try:
                self.drive.command_position(kwargs.pop("velocity_hz"), **kwargs)
                return
            except SimulationError:  # a value the firmware would refuse (a velocity not finite, ...): stopped
                _error(writer, mp.WRITE_ERROR, Register.COMMAND_VELOCITY, _UNKNOWN_REGISTER)
        self.drive.command_stop()
        if mode != Mode.STOPPED:  # the emulated drive runs no other mode: stopped, and said so
            _error(writer, mp.WRITE_ERROR, Register.MODE, _UNKNOWN_REGISTER)

    def _read(self, sub: mp.RegisterSubframe, status: DriveStatus, writer: mp.WriteFrame) -> None:
        """A REPLY subframe of the register read ``sub`` at its resolution, then an error per register not held."""
        register, resolution = sub.register, sub.resolution
        if register in _STATUS_REGISTERS:
            value = float(_STATUS_REGISTERS[register](status))
            raw = mp.saturate(value, resolution, scale_register(register, resolution, 1))
        elif register == Register.MILLISECOND_COUNTER:
            ms = int(self.drive.time_s * 1000.0) % 2**32
            raw = [_wrapped(ms, 8), _wrapped(ms, 16), _wrapped(ms, 32), float(ms % 8388608)][resolution]
        else:
            _error(writer, mp.READ_ERROR, register, _UNKNOWN_REGISTER)
            return
        if writer.size() + 2 + 5 + mp.resolution_size(resolution) > _MAX_FRAME:
            return
        writer.write_int8(mp.REPLY_BASE | (resolution << 2) | 1)
        writer.write_varuint(register)
        writer.write(raw, resolution)

    # ------------------------------------------------------------------ the text console

    def _console(self, data: bytes) -> None:
        self._console_in += data
        while True:
            ends = [i for i in (self._console_in.find(b"\n"), self._console_in.find(b"\r")) if i >= 0]
            if not ends:
                break
            line, self._console_in = self._console_in[:min(ends)], self._console_in[min(ends) + 1:]
            if line.strip():
                self._answer(self._execute(line.decode("latin1").split()))
        if len(self._console_in) > _MAX_LINE:
            self._console_in = b""
            self._answer("ERR line too long")

    def _answer(self, text: str) -> None:
        self._console_out = (self._console_out + text.encode("latin1") + b"\r\n")[-_MAX_OUTPUT:]

    def _execute(self, words: list[str]) -> str:
        """One console line's answer: ``OK``, a value, or ``ERR ...`` as the firmware words them."""
        match words:
            case ["tel", "stop"]:
                return "OK"
            case ["d", "stop"]:
                self.drive.command_stop()
                return "OK"
            case ["conf", "get", name]:
                value = self.drive.config.get(name)
                return "ERR error reading" if value is None else repr(float(value))
            case ["conf", "set", name, text]:
                try:
                    self.drive.set_config(name, float(text))
                except (KeyError, ValueError, SimulationError):  # unknown name, not a number, out of its range
                    return "ERR error setting"
                return "OK"
            case ["conf", "write"]:
                self.drive.write_flash()
                return "OK"
        return "ERR unknown command"


def _wrapped(value: int, bits: int) -> int:
    """``value`` modulo 2**bits as a signed integer of that many bits (the firmware's cast)."""
    value %= 2**bits
    return value - 2**bits if value >= 2 ** (bits - 1) else value


def _error(writer: mp.WriteFrame, kind: int, register: int, code: int) -> None:
    if writer.size() + 11 > _MAX_FRAME:
        return
    writer.write_int8(kind)
    writer.write_varuint(register)
    writer.write_varuint(code)
