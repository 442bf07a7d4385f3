"""The bench protocol: framed binary messages between a client and a bench target over TCP.

docs/protocol.md is the specification (byte-exact layouts for firmware
authors); this module implements both ends of it. Every frame is a 16-byte
header (magic, version, type, sequence number, payload length), the payload
and a CRC32 of header and payload. Numbers are little-endian; arrays travel
as raw float64/int64 blocks of known length, decoded with `numpy.frombuffer`
(no per-sample Python work). Nothing the peer sends is ever executed.
"""

from __future__ import annotations

import select
import socket
import struct
import time
import zlib
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from types import MappingProxyType
from typing import Iterator, Mapping, Sequence

import numpy as np

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.core.errors import BackendError
from ilcpmac.core.records import MOTOR_RANGES, MotorInfo, SensorCalibration, TrialData, TrialRequest
from ilcpmac.pipeline.safety import SafetyLimits, request_violation

#: Protocol version carried in every frame header; both ends must speak the same.
PROTOCOL_VERSION = 1
#: The first four bytes of every frame (ASCII "ILCP").
MAGIC = b"ILCP"
#: Largest payload of any frame, bytes (each frame type has its own, smaller or equal bound: PAYLOAD_BOUNDS).
MAX_PAYLOAD = 16 * 1024 * 1024
#: Largest ERROR message, bytes of UTF-8 (longer ones are truncated by the sender).
MAX_ERROR_MESSAGE = 1024
#: A target running a trial sends some frame (DATA or HEARTBEAT) at least this often, s.
HEARTBEAT_INTERVAL_S = 1.0

HEADER = struct.Struct("<4sHHII")  # magic, version, type, sequence, payload length
CRC = struct.Struct("<I")
_DESCRIBE_HEAD = struct.Struct("<IIII11d")
_REQUEST_HEAD = struct.Struct("<IIII9d")
_ACCEPT = struct.Struct("<IIQ")
_DATA_HEAD = struct.Struct("<IIQII")
_END = struct.Struct("<IIQII")
_HEARTBEAT = struct.Struct("<II")
_ERROR_HEAD = struct.Struct("<II")
_F64 = np.dtype("<f8")
_I64 = np.dtype("<i8")
#: DESCRIBE ``flags`` bit: the bench has no torque sensor (DATA's ``torque`` column is then ignored).
NO_TORQUE_SENSOR = 1
#: Most encoder counts per revolution a bench can serve: its DESCRIBE carries 24 bytes per count
#: (docs/protocol.md, 5.1) within MAX_PAYLOAD. A finer encoder is served at a divided resolution.
MAX_COUNTS_PER_REV = (MAX_PAYLOAD - _DESCRIBE_HEAD.size) // 24


class FrameType(IntEnum):
    """The frame types (header field ``type``)."""

    HELLO = 1
    DESCRIBE = 2
    REQUEST = 3
    ACCEPT = 4
    DATA = 5
    HEARTBEAT = 6
    END_OF_TRIAL = 7
    ERROR = 8


class ErrorCode(IntEnum):
    """Codes of ERROR frames."""

    VERSION_MISMATCH = 1
    MALFORMED_FRAME = 2
    UNEXPECTED_FRAME = 3
    BAD_REQUEST = 4
    LIMIT_EXCEEDED = 5
    TRIAL_FAILED = 6
    BUSY = 7
    INTERNAL = 8


class Column(IntFlag):
    """Flags of the optional TrialData columns present in DATA frames."""

    I_MEAS = 1
    TORQUE_TRUE = 2
    I_TRUE = 4
    SPEED_TRUE = 8


#: Every TrialData column in wire order: (attribute, width, dtype, flag or None if always present).
COLUMNS: tuple[tuple[str, int, np.dtype, Column | None], ...] = (
    ("count", 1, _I64, None),
    ("time_s", 1, _F64, None),
    ("i_ref_a", 3, _F64, None),
    ("torque_nm", 1, _F64, None),
    ("i_meas_a", 3, _F64, Column.I_MEAS),
    ("torque_true_nm", 1, _F64, Column.TORQUE_TRUE),
    ("i_true_a", 3, _F64, Column.I_TRUE),
    ("speed_true_rad_s", 1, _F64, Column.SPEED_TRUE),
)
_ALL_COLUMNS = int(Column.I_MEAS | Column.TORQUE_TRUE | Column.I_TRUE | Column.SPEED_TRUE)
_MAX_WIDTH = sum(width for _, width, _, _ in COLUMNS)

#: Largest payload of each frame type, bytes, as far as the frame type alone fixes it (docs/protocol.md,
#: section 3). A receiver may tighten a bound once it knows more (`Channel.bounds`, `target_bounds`,
#: `data_bound`).
PAYLOAD_BOUNDS: Mapping[FrameType, int] = MappingProxyType({
    FrameType.HELLO: 0,
    FrameType.DESCRIBE: MAX_PAYLOAD,
    FrameType.REQUEST: MAX_PAYLOAD,
    FrameType.ACCEPT: _ACCEPT.size,
    FrameType.DATA: MAX_PAYLOAD,
    FrameType.HEARTBEAT: _HEARTBEAT.size,
    FrameType.END_OF_TRIAL: _END.size,
    FrameType.ERROR: _ERROR_HEAD.size + MAX_ERROR_MESSAGE,
})
#: Payload bytes read before the receive buffer grows with what arrives (larger frames grow it by doubling).
_FIRST_READ = 1024 * 1024


def target_bounds(counts_per_rev: int) -> dict[FrameType, int]:
    """Payload bounds of the frames a target of ``counts_per_rev`` counts accepts: HELLO (empty), REQUEST
    (exactly its table length) and ERROR; 0 for the frame types only a target sends."""
    return {**dict.fromkeys(FrameType, 0), FrameType.REQUEST: _REQUEST_HEAD.size + 16 * counts_per_rev,
            FrameType.ERROR: PAYLOAD_BOUNDS[FrameType.ERROR]}


def data_bound(max_samples: int) -> int:
    """Largest DATA payload of a trial of at most ``max_samples`` samples (every column present), bytes."""
    return min(_DATA_HEAD.size + 8 * _MAX_WIDTH * max_samples, MAX_PAYLOAD)


class ProtocolError(BackendError):
    """A frame or message breaks the protocol: bad magic, CRC, length, sequence or order.

    The byte stream can no longer be trusted; the connection must be closed.
    A client may retry on a new connection.
    """


class PeerClosed(ProtocolError):
    """The peer closed the connection between two frames."""


class FrameTimeout(ProtocolError):
    """A frame was not complete in time: the peer dribbles it, or a deadline passed."""


class ProtocolVersionError(BackendError):
    """The peer speaks another protocol version (retrying cannot help)."""


class TargetError(BackendError):
    """The peer answered with an ERROR frame.

    Attributes
    ----------
    code : ErrorCode or int
        The error code (an int when it is not one this version knows).
    trial_id : int
        The trial it concerns, 0 for none.
    detail : str
        The peer's message.
    """

    def __init__(self, code: ErrorCode | int, trial_id: int, detail: str) -> None:
        self.code = code
        self.trial_id = trial_id
        self.detail = detail
        name = code.name if isinstance(code, ErrorCode) else f"code {code}"
        super().__init__(f"target error {name}: {detail}")


@dataclass(frozen=True)
class Frame:
    """One received frame.

    Attributes
    ----------
    type : FrameType
    version : int
        Protocol version of the header (differs from ours only on ERROR frames).
    seq : int
        The sender's sequence number of this frame.
    payload : memoryview
        The payload bytes (CRC already verified).
    """

    type: FrameType
    version: int
    seq: int
    payload: memoryview


# ---------------------------------------------------------------- framing


class Channel:
    """One framed connection: numbers outgoing frames 0, 1, 2... (mod 2^32) and checks the peer's numbering.

    Parameters
    ----------
    sock : socket.socket
        A connected stream socket; its timeout (set it before) applies to every read: the longest
        silence accepted.
    peer : str
        How to name the peer in error messages.
    bounds : mapping of FrameType to int
        Largest payload accepted per frame type, bytes; kept (as a dict the owner may tighten) in
        `bounds`. A frame announcing more is refused before its payload is read.
    frame_timeout_s : float or None
        If given, a frame must arrive complete within this many seconds of its first byte, and a
        frame must be sent within it (a peer that dribbles a frame, or does not read, is cut off).
    """

    def __init__(self, sock: socket.socket, peer: str, bounds: Mapping[FrameType, int] = PAYLOAD_BOUNDS,
                 frame_timeout_s: float | None = None) -> None:
        self.sock = sock
        self.peer = peer
        self.bounds = dict(bounds)
        self.frame_timeout_s = frame_timeout_s
        self._timeout_s = sock.gettimeout()
        self._send_seq = 0
        self._recv_seq = 0

    def frame_bytes(self, ftype: FrameType, parts: Sequence = (), version: int = PROTOCOL_VERSION) -> bytearray:
        """The wire bytes of the next frame, numbered and CRC-sealed (``send_bytes`` sends them).

        Parameters
        ----------
        ftype : FrameType
        parts : sequence of bytes-like objects (C-contiguous numpy arrays allowed)
            The payload, concatenated.
        version : int
            Header version (only fault injection uses another than ours).
        """
        views = [memoryview(p).cast("B") for p in parts]
        length = sum(v.nbytes for v in views)
        if length > MAX_PAYLOAD:
            raise ProtocolError(f"{ftype.name} payload of {length} bytes exceeds the {MAX_PAYLOAD}-byte maximum")
        buf = bytearray(HEADER.size + length + CRC.size)
        HEADER.pack_into(buf, 0, MAGIC, version, ftype, self._send_seq, length)
        offset = HEADER.size
        for v in views:
            buf[offset:offset + v.nbytes] = v
            offset += v.nbytes
        CRC.pack_into(buf, offset, zlib.crc32(memoryview(buf)[:offset]))
        self._send_seq = (self._send_seq + 1) & 0xFFFFFFFF
        return buf

    def send_bytes(self, frame: bytes | bytearray) -> None:
        """Send a frame made by `frame_bytes` (within ``frame_timeout_s`` if set)."""
        if self.frame_timeout_s is None:
            self.sock.sendall(frame)
            return
        self.sock.settimeout(self.frame_timeout_s)
        try:
            self.sock.sendall(frame)
        except TimeoutError:
            raise FrameTimeout(f"{self.peer} did not take a frame within {self.frame_timeout_s:g} s") from None
        finally:
            self.sock.settimeout(self._timeout_s)

    def send(self, ftype: FrameType, parts: Sequence = ()) -> None:
        """Build and send one frame."""
        self.send_bytes(self.frame_bytes(ftype, parts))

    def _receive(self, view: memoryview, deadline: float | None) -> int:
        """One read into ``view`` (0 when the peer closed), cut short at ``deadline`` (time.monotonic)."""
        if deadline is None:
            return self.sock.recv_into(view)
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise FrameTimeout(f"{self.peer} sent no complete frame in time")
        self.sock.settimeout(remaining if self._timeout_s is None else min(remaining, self._timeout_s))
        try:
            return self.sock.recv_into(view)
        except TimeoutError:
            if time.monotonic() >= deadline:
                raise FrameTimeout(f"{self.peer} sent no complete frame in time") from None
            raise

    def _fill(self, view: memoryview, got: int, deadline: float | None) -> None:
        """Read until ``view`` is full (``got`` bytes of it are already there)."""
        while got < view.nbytes:
            k = self._receive(view[got:], deadline)
            if k == 0:
                raise ProtocolError(f"{self.peer} closed the connection mid-frame")
            got += k

    def recv(self, deadline: float | None = None) -> Frame:
        """Read one frame and verify magic, type, length, CRC, sequence number and version.

        The payload buffer is allocated only once the length passed its type's bound, and beyond
        1 MiB grows only as bytes arrive.

        Parameters
        ----------
        deadline : float or None
            ``time.monotonic()`` by which the whole frame must have arrived.

        Raises
        ------
        PeerClosed
            The peer closed the connection before the frame's first byte.
        FrameTimeout
            The frame was not complete by ``deadline`` or within ``frame_timeout_s`` of its first byte.
        ProtocolError
            Bad magic, unknown frame type, a length beyond the type's bound, truncated frame, CRC
            mismatch or sequence gap.
        ProtocolVersionError
            A frame other than ERROR with another protocol version.
        TimeoutError
            No byte within the socket's timeout.
        """
        try:
            header = bytearray(HEADER.size)
            view = memoryview(header)
            got = self._receive(view, deadline)
            if got == 0:
                raise PeerClosed(f"{self.peer} closed the connection")
            if self.frame_timeout_s is not None:
                cut = time.monotonic() + self.frame_timeout_s
                deadline = cut if deadline is None else min(deadline, cut)
            self._fill(view, got, deadline)
            magic, version, ftype, seq, length = HEADER.unpack(header)
            if magic != MAGIC:
                raise ProtocolError(f"bad magic {bytes(magic)!r} in a frame header from {self.peer}")
            try:
                kind = FrameType(ftype)
            except ValueError:
                raise ProtocolError(f"unknown frame type {ftype} from {self.peer}") from None
            if length > self.bounds[kind]:
                raise ProtocolError(f"{kind.name} frame from {self.peer} announces {length} payload bytes "
                                    f"(at most {self.bounds[kind]})")
            body = bytearray(min(length + CRC.size, _FIRST_READ))
            got = 0
            while True:
                self._fill(memoryview(body), got, deadline)
                if len(body) == length + CRC.size:
                    break
                got = len(body)
                body.extend(bytes(min(got, length + CRC.size - got)))
        finally:
            if deadline is not None:
                self.sock.settimeout(self._timeout_s)
        view = memoryview(body)
        (crc,) = CRC.unpack_from(body, length)
        if zlib.crc32(view[:length], zlib.crc32(header)) != crc:
            raise ProtocolError(f"CRC mismatch in frame {seq} ({kind.name}) from {self.peer}")
        if seq != self._recv_seq:
            raise ProtocolError(f"sequence gap from {self.peer}: expected frame {self._recv_seq}, got {seq}")
        self._recv_seq = (self._recv_seq + 1) & 0xFFFFFFFF
        if version != PROTOCOL_VERSION and kind is not FrameType.ERROR:
            raise ProtocolVersionError(f"{self.peer} speaks protocol version {version}, "
                                       f"this end speaks version {PROTOCOL_VERSION}")
        return Frame(kind, version, seq, view[:length])

    def peer_closed(self) -> bool:
        """Whether the peer has closed or reset the connection (nothing is read from it)."""
        try:
            readable, _, _ = select.select([self.sock], [], [], 0)
            return bool(readable) and self.sock.recv(1, socket.MSG_PEEK) == b""
        except (OSError, ValueError):  # reset, or already closed here
            return True

    def shutdown(self) -> None:
        """Shut the connection down: wakes a thread blocked on it, which then fails (and closes it)."""
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass  # already closed by the peer

    def close(self) -> None:
        """Shut the connection down and close it."""
        self.shutdown()
        self.sock.close()


# ---------------------------------------------------------------- messages


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=_F64)


def _expect_size(payload: memoryview, size: int, what: str) -> None:
    if payload.nbytes != size:
        raise ProtocolError(f"{what} payload is {payload.nbytes} bytes, expected {size}")


def check_servable(description: BenchDescription) -> None:
    """Raise `BackendError` if ``description``'s DESCRIBE would not fit in a frame (`MAX_COUNTS_PER_REV`), or not
    tell what its counts are (DESCRIBE tells no count means, `MotorInfo.lines_per_count`)."""
    cpr = description.motor.counts_per_rev
    if description.motor.lines_per_count != 1:
        raise BackendError(f"a bench whose counts are means over {description.motor.lines_per_count} lines: DESCRIBE "
                           "tells the edges of its counts only; serve the edge of every line it samples")
    if cpr > MAX_COUNTS_PER_REV:
        raise BackendError(f"counts_per_rev {cpr} is more than the protocol's {MAX_COUNTS_PER_REV}: DESCRIBE "
                           f"carries 24 bytes per count within {MAX_PAYLOAD} bytes; serve the encoder at a divided "
                           "resolution")


def encode_describe(description: BenchDescription) -> list:
    """Payload parts of DESCRIBE: the [motor] and [sensors] data, the limits and the back-EMF table."""
    check_servable(description)
    m, cal, lim = description.motor, description.calibration, description.limits
    backemf = _f64(description.backemf_nm_per_a)
    if backemf.shape != (m.counts_per_rev, 3):
        raise BackendError(f"back-EMF table has shape {backemf.shape}, expected ({m.counts_per_rev}, 3)")
    flags = 0 if m.torque_sensor else NO_TORQUE_SENSOR
    head = _DESCRIBE_HEAD.pack(m.pole_pairs, m.slots, m.counts_per_rev, flags, m.inertia_kgm2,
                               *cal.current_scale, *cal.current_offset, cal.torque_gain,
                               lim.max_current_a, lim.max_torque_nm, lim.max_speed_hz)
    return [head, backemf]


def decode_describe(payload: memoryview) -> BenchDescription:
    """BenchDescription from a DESCRIBE payload.

    Raises
    ------
    ProtocolError
        The payload's size does not match its counts_per_rev.
    BackendError
        A value no bench has: [motor] data outside the bench format's MOTOR_RANGES, a
        non-finite or non-positive scale, gain or limit, non-finite offsets or back-EMF.
    """
    if payload.nbytes < _DESCRIBE_HEAD.size:
        raise ProtocolError(f"DESCRIBE payload is {payload.nbytes} bytes, shorter than its "
                            f"{_DESCRIBE_HEAD.size}-byte head")
    pole_pairs, slots, cpr, flags, inertia, *v = _DESCRIBE_HEAD.unpack_from(payload)
    _expect_size(payload, _DESCRIBE_HEAD.size + 24 * cpr, f"DESCRIBE (counts_per_rev = {cpr})")
    if flags & ~NO_TORQUE_SENSOR:
        raise BackendError(f"DESCRIBE flags {flags:#x}: unknown bits (only {NO_TORQUE_SENSOR:#x}, no torque sensor, "
                           "is defined)")
    motor = {"pole_pairs": pole_pairs, "slots": slots, "counts_per_rev": cpr, "inertia": inertia}
    for key, (low, high) in MOTOR_RANGES.items():
        if not low <= motor[key] <= high:
            raise BackendError(f"DESCRIBE {key} must lie in [{low}, {high}], got {motor[key]!r}")
    positive = {"current_scale": v[0:3], "torque_gain": v[6:7], "max_current_a": v[7:8], "max_torque_nm": v[8:9],
                "max_speed_hz": v[9:10]}
    for key, values in positive.items():
        if not all(0 < x < np.inf for x in values):
            raise BackendError(f"DESCRIBE {key} must be positive and finite, got {values}")
    backemf = np.frombuffer(payload, _F64, 3 * cpr, _DESCRIBE_HEAD.size).reshape(cpr, 3).astype(float)
    if not (np.isfinite(v[3:6]).all() and np.isfinite(backemf).all()):
        raise BackendError("DESCRIBE current_offset and back-EMF table must be finite")
    return BenchDescription(
        motor=MotorInfo(pole_pairs, slots, cpr, inertia, torque_sensor=not flags & NO_TORQUE_SENSOR),
        backemf_nm_per_a=backemf,
        calibration=SensorCalibration(v[0:3], v[3:6], v[6]),
        limits=BenchLimits(max_current_a=v[7], max_torque_nm=v[8], max_speed_hz=v[9]),
    )


def encode_request(trial_id: int, request: TrialRequest) -> list:
    """Payload parts of REQUEST: everything in ``request``, seed included."""
    ff, exc = _f64(request.feedforward_nm), _f64(request.excitation_nm)
    cal = request.calibration
    head = _REQUEST_HEAD.pack(trial_id, request.revolutions, request.seed, ff.size,
                              request.torque_setpoint_nm, request.speed_setpoint_hz,
                              *cal.current_scale, *cal.current_offset, cal.torque_gain)
    return [head, ff, exc]


def decode_request(payload: memoryview) -> tuple[int, TrialRequest]:
    """(trial id, TrialRequest) from a REQUEST payload."""
    if payload.nbytes < _REQUEST_HEAD.size:
        raise ProtocolError(f"REQUEST payload is {payload.nbytes} bytes, shorter than its "
                            f"{_REQUEST_HEAD.size}-byte head")
    trial_id, revolutions, seed, n, torque, speed, *v = _REQUEST_HEAD.unpack_from(payload)
    _expect_size(payload, _REQUEST_HEAD.size + 16 * n, f"REQUEST (table length {n})")
    tables = np.frombuffer(payload, _F64, 2 * n, _REQUEST_HEAD.size).astype(float)
    return trial_id, TrialRequest(
        torque_setpoint_nm=torque, speed_setpoint_hz=speed, revolutions=revolutions,
        feedforward_nm=tables[:n], excitation_nm=tables[n:],
        calibration=SensorCalibration(v[0:3], v[3:6], v[6]), seed=seed)


@dataclass(frozen=True)
class Accept:
    """ACCEPT: the target starts trial ``trial_id`` and sends at most ``max_samples`` samples."""

    trial_id: int
    max_samples: int


def encode_accept(accept: Accept) -> list:
    """Payload parts of ACCEPT."""
    return [_ACCEPT.pack(accept.trial_id, 0, accept.max_samples)]


def decode_accept(payload: memoryview) -> Accept:
    """Accept from an ACCEPT payload."""
    _expect_size(payload, _ACCEPT.size, "ACCEPT")
    trial_id, _, max_samples = _ACCEPT.unpack(payload)
    return Accept(trial_id, max_samples)


def encode_heartbeat(trial_id: int) -> list:
    """Payload parts of HEARTBEAT."""
    return [_HEARTBEAT.pack(trial_id, 0)]


def decode_heartbeat(payload: memoryview) -> int:
    """The trial id of a HEARTBEAT payload."""
    _expect_size(payload, _HEARTBEAT.size, "HEARTBEAT")
    return _HEARTBEAT.unpack(payload)[0]


def encode_error(code: ErrorCode, trial_id: int, message: str) -> list:
    """Payload parts of ERROR (message cut to MAX_ERROR_MESSAGE bytes of UTF-8)."""
    text = message.encode("utf-8")[:MAX_ERROR_MESSAGE].decode("utf-8", "ignore").encode("utf-8")
    return [_ERROR_HEAD.pack(code, trial_id), text]


def decode_error(payload: memoryview) -> TargetError:
    """The TargetError an ERROR payload reports."""
    if payload.nbytes < _ERROR_HEAD.size or payload.nbytes > _ERROR_HEAD.size + MAX_ERROR_MESSAGE:
        raise ProtocolError(f"ERROR payload is {payload.nbytes} bytes, expected "
                            f"{_ERROR_HEAD.size} to {_ERROR_HEAD.size + MAX_ERROR_MESSAGE}")
    code, trial_id = _ERROR_HEAD.unpack_from(payload)
    detail = bytes(payload[_ERROR_HEAD.size:]).decode("utf-8", "replace")
    try:
        code = ErrorCode(code)
    except ValueError:
        pass  # an unknown code is still reported, as a number
    return TargetError(code, trial_id, detail)


@dataclass(frozen=True)
class EndOfTrial:
    """END_OF_TRIAL: how many DATA frames and samples were sent and the CRC32 of their payloads."""

    trial_id: int
    data_frames: int
    n_samples: int
    trial_crc: int


def encode_end(end: EndOfTrial) -> list:
    """Payload parts of END_OF_TRIAL."""
    return [_END.pack(end.trial_id, end.data_frames, end.n_samples, end.trial_crc, 0)]


def decode_end(payload: memoryview) -> EndOfTrial:
    """EndOfTrial from an END_OF_TRIAL payload."""
    _expect_size(payload, _END.size, "END_OF_TRIAL")
    trial_id, frames, samples, crc, _ = _END.unpack(payload)
    return EndOfTrial(trial_id, frames, samples, crc)


def trial_columns(trial: TrialData) -> tuple[Column, list[np.ndarray]]:
    """The flags and the wire-ready (contiguous, little-endian) columns of ``trial``."""
    flags = Column(0)
    columns = []
    for name, width, dtype, flag in COLUMNS:
        value = getattr(trial, name)
        if value is None:
            continue
        array = np.ascontiguousarray(value, dtype=dtype)
        if array.shape != ((trial.n_samples, 3) if width == 3 else (trial.n_samples,)):
            raise BackendError(f"trial column {name} has shape {array.shape} for {trial.n_samples} samples")
        columns.append(array)
        if flag is not None:
            flags |= flag
    return flags, columns


def encode_trial(trial_id: int, trial: TrialData, chunk_samples: int) -> Iterator[tuple[FrameType, list]]:
    """The DATA frames of ``trial`` (``chunk_samples`` rows each) and its END_OF_TRIAL, as (type, parts)."""
    flags, columns = trial_columns(trial)
    crc = 0
    frames = 0
    for start in range(0, trial.n_samples, chunk_samples):
        stop = min(start + chunk_samples, trial.n_samples)
        parts: list[bytes | np.ndarray] = [_DATA_HEAD.pack(trial_id, flags, start, stop - start, 0),
                                           *(c[start:stop] for c in columns)]
        for p in parts:
            # an ndarray is a buffer; numpy's stubs say so (__buffer__) only for Python >= 3.12
            crc = zlib.crc32(p, crc)  # type: ignore[arg-type]
        frames += 1
        yield FrameType.DATA, parts
    yield FrameType.END_OF_TRIAL, encode_end(EndOfTrial(trial_id, frames, trial.n_samples, crc))


#: Samples may exceed the bench's announced limits by this factor at most (noise, overshoot, sensor
#: offsets); a value beyond it is not a measurement of that bench.
SAMPLE_MARGIN = 4.0


@dataclass(frozen=True)
class SampleBounds:
    """What the samples of one requested trial may hold (docs/protocol.md, section 5.4).

    Attributes
    ----------
    max_samples : int
        revolutions x counts_per_rev of the request: the most samples the trial may have, and the
        largest span of its counts (last - first + 1).
    max_abs : mapping of str to float
        Largest |value| of each bounded column (TrialData attribute); a NaN or infinite value is beyond it.
    """

    max_samples: int
    max_abs: Mapping[str, float]

    @classmethod
    def of(cls, request: TrialRequest, description: BenchDescription) -> SampleBounds:
        """The bounds of ``request`` on the described bench: SAMPLE_MARGIN x max_current_a for the current
        references and true currents, x max_torque_nm for the true torque, x 2 pi max_speed_hz for the true
        speed (rad/s); the measured currents and torque get these bounds as the request's calibration
        converts them from the described one (its scale ratio, plus its offset change)."""
        limits, now, cal = description.limits, description.calibration, request.calibration
        current = SAMPLE_MARGIN * limits.max_current_a
        torque = SAMPLE_MARGIN * limits.max_torque_nm
        offset = np.abs(cal.current_offset - now.current_offset)
        measured = (now.current_scale * current + offset) / cal.current_scale
        return cls(request.revolutions * description.motor.counts_per_rev, {
            "i_ref_a": current, "i_meas_a": float(np.max(measured)), "i_true_a": current,
            "torque_nm": torque * now.torque_gain / cal.torque_gain, "torque_true_nm": torque,
            "speed_true_rad_s": SAMPLE_MARGIN * 2 * np.pi * limits.max_speed_hz})


class TrialAssembler:
    """Collects the DATA frames of one trial, validating every sample, and verifies them against its END_OF_TRIAL.

    Parameters
    ----------
    trial_id : int
        The trial the frames must belong to.
    max_samples : int
        The most samples the target announced in ACCEPT (at most ``bounds.max_samples``).
    bounds : SampleBounds
        What the samples may hold: counts strictly increasing within the requested span, time
        stamps finite and strictly increasing, bounded columns within their bounds.
    """

    def __init__(self, trial_id: int, max_samples: int, bounds: SampleBounds) -> None:
        self.trial_id = trial_id
        self.max_samples = max_samples
        self.bounds = bounds
        self.flags: Column | None = None
        self.n_samples = 0
        self.data_frames = 0
        self._crc = 0
        self._chunks: list[dict[str, np.ndarray]] = []
        self._first_count = 0

    def add(self, payload: memoryview) -> None:
        """Decode one DATA payload; raise ProtocolError unless it continues this trial with valid samples."""
        if payload.nbytes < _DATA_HEAD.size:
            raise ProtocolError(f"DATA payload is {payload.nbytes} bytes, shorter than its "
                                f"{_DATA_HEAD.size}-byte head")
        trial_id, flags, first, n, _ = _DATA_HEAD.unpack_from(payload)
        if trial_id != self.trial_id:
            raise ProtocolError(f"DATA frame of trial {trial_id} during trial {self.trial_id}")
        if flags & ~_ALL_COLUMNS:
            raise ProtocolError(f"DATA frame has unknown column flags {flags:#x}")
        if self.flags is not None and flags != self.flags:
            raise ProtocolError(f"DATA column flags changed from {int(self.flags):#x} to {flags:#x} mid-trial")
        if first != self.n_samples:
            raise ProtocolError(f"DATA frame starts at sample {first}, expected {self.n_samples}")
        if n == 0 or first + n > self.max_samples:
            raise ProtocolError(f"DATA frame of {n} samples at {first} (at most {self.max_samples} announced)")
        widths = [w for _, w, _, flag in COLUMNS if flag is None or flags & flag]
        _expect_size(payload, _DATA_HEAD.size + 8 * n * sum(widths), f"DATA ({n} samples, flags {flags:#x})")
        chunk, offset = {}, _DATA_HEAD.size
        for (name, width, dtype, flag) in COLUMNS:
            if flag is None or flags & flag:
                array = np.frombuffer(payload, dtype, n * width, offset)
                chunk[name] = array.reshape(n, 3) if width == 3 else array
                offset += 8 * n * width
        self._check(first, chunk)
        self.flags = Column(flags)
        self._crc = zlib.crc32(payload, self._crc)
        self._chunks.append(chunk)
        self.n_samples += n
        self.data_frames += 1

    def _check(self, first: int, chunk: dict[str, np.ndarray]) -> None:
        """Raise ProtocolError naming the first sample of ``chunk`` (trial samples from ``first``) at fault."""
        for name in ("count", "time_s"):
            self._check_rising(first, name, chunk[name])
        count = chunk["count"]
        if first == 0:
            self._first_count = int(count[0])
        last = min(self._first_count + self.bounds.max_samples - 1, np.iinfo(np.int64).max)
        if count[-1] > last:
            bad = int(np.argmax(count > last))
            raise ProtocolError(f"DATA sample {first + bad}: count {count[bad]} lies beyond the "
                                f"{self.bounds.max_samples} requested counts from the first ({self._first_count})")
        for name, bound in self.bounds.max_abs.items():
            column = chunk.get(name)
            if column is not None and not (column.max() <= bound and column.min() >= -bound):
                within = np.abs(column) <= bound
                bad = int(np.argmin(within.all(axis=1) if column.ndim == 2 else within))
                raise ProtocolError(f"DATA sample {first + bad}: {name} {column[bad]} is not finite or beyond "
                                    f"+-{bound:.4g} (bound from the bench's limits)")

    def _check_rising(self, first: int, name: str, column: np.ndarray) -> None:
        previous = self._chunks[-1][name][-1] if self._chunks else None
        rising = column[1:] > column[:-1]
        if (rising.all() and np.isfinite(column[[0, -1]]).all()
                and (previous is None or column[0] > previous)):
            return
        ok = np.isfinite(column) & np.concatenate([[previous is None or column[0] > previous], rising])
        bad = int(np.argmin(ok))
        before = column[bad - 1] if bad else previous
        raise ProtocolError(f"DATA sample {first + bad}: {name} {column[bad]}"
                            f"{'' if before is None else f' after {before}'} (must be finite and increase strictly)")

    def finish(self, payload: memoryview) -> dict[str, np.ndarray]:
        """Verify the END_OF_TRIAL payload; return the trial's columns by TrialData attribute."""
        end = decode_end(payload)
        if end.trial_id != self.trial_id:
            raise ProtocolError(f"END_OF_TRIAL of trial {end.trial_id} during trial {self.trial_id}")
        if (end.n_samples, end.data_frames) != (self.n_samples, self.data_frames):
            raise ProtocolError(f"END_OF_TRIAL announces {end.n_samples} samples in {end.data_frames} frames, "
                                f"received {self.n_samples} in {self.data_frames}")
        if end.trial_crc != self._crc:
            raise ProtocolError(f"trial checksum mismatch: END_OF_TRIAL says {end.trial_crc:#010x}, "
                                f"received data gives {self._crc:#010x}")
        if self.n_samples < 2:
            raise ProtocolError(f"trial has {self.n_samples} samples, at least 2 are needed")
        return {name: np.concatenate([c[name] for c in self._chunks]).astype(array.dtype.newbyteorder("="),
                                                                               copy=False)
                for name, array in self._chunks[0].items()}


# ---------------------------------------------------------------- requests a target accepts


def check_trial_id(trial_id: int) -> tuple[ErrorCode, str] | None:
    """Why a target must refuse a REQUEST's ``trial_id`` (section 5.2: at least 1; 0 names no trial in an
    ERROR), or None."""
    if trial_id >= 1:
        return None
    return ErrorCode.BAD_REQUEST, f"trial_id {trial_id}: a REQUEST's trial_id is at least 1 (0 names no trial)"


def check_request(request: TrialRequest, description: BenchDescription) -> tuple[ErrorCode, str] | None:
    """Why a target described by ``description`` must refuse ``request``, or None.

    `ilcpmac.pipeline.safety.request_violation` against the described limits: BAD_REQUEST for a
    malformed request (table lengths other than counts_per_rev, wrong types, NaN or infinity, revolutions
    below 1, a seed outside 32 bits, a non-positive speed or calibration); LIMIT_EXCEEDED for a speed
    above max_speed_hz, a peak |set point + feed-forward + excitation| above max_torque_nm, or a peak
    current reference i*_p = tau_ref K_p / sum_q K_q^2 (the minimum-copper-loss references from the
    described back-EMF table) above max_current_a.
    """
    violation = request_violation(request, description, SafetyLimits.of_bench(description.limits))
    if violation is None:
        return None
    return (ErrorCode.BAD_REQUEST if violation.malformed else ErrorCode.LIMIT_EXCEEDED), violation.message
