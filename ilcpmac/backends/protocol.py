"""The bench protocol: framed binary messages between a client and a bench target over TCP.

docs/protocol.md is the specification (byte-exact layouts for firmware
authors); this module implements both ends of it. Every frame is a 16-byte
header (magic, version, type, sequence number, payload length), the payload
and a CRC32 of header and payload. Numbers are little-endian; arrays travel
as raw float64/int64 blocks of known length, decoded with `numpy.frombuffer`
(no per-sample Python work). Nothing the peer sends is ever executed.
"""

from __future__ import annotations

import socket
import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import Iterator, Sequence

import numpy as np

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.bench.format import MotorInfo
from ilcpmac.errors import BackendError
from ilcpmac.model.tables import current_references
from ilcpmac.records import SensorCalibration, TrialData, TrialRequest

#: Protocol version carried in every frame header; both ends must speak the same.
PROTOCOL_VERSION = 1
#: The first four bytes of every frame (ASCII "ILCP").
MAGIC = b"ILCP"
#: Largest accepted payload, bytes (a larger length field is a malformed frame).
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


_FRAME_TYPES = {t.value for t in FrameType}


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


class ProtocolError(BackendError):
    """A frame or message breaks the protocol: bad magic, CRC, length, sequence or order.

    The byte stream can no longer be trusted; the connection must be closed.
    A client may retry on a new connection.
    """


class PeerClosed(ProtocolError):
    """The peer closed the connection between two frames."""


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
        A connected stream socket; its timeout applies to every read.
    peer : str
        How to name the peer in error messages.
    """

    def __init__(self, sock: socket.socket, peer: str) -> None:
        self.sock = sock
        self.peer = peer
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
        """Send a frame made by `frame_bytes`."""
        self.sock.sendall(frame)

    def send(self, ftype: FrameType, parts: Sequence = ()) -> None:
        """Build and send one frame."""
        self.send_bytes(self.frame_bytes(ftype, parts))

    def _read_exact(self, n: int, frame_start: bool) -> bytearray:
        buf = bytearray(n)
        view = memoryview(buf)
        got = 0
        while got < n:
            k = self.sock.recv_into(view[got:], n - got)
            if k == 0:
                if frame_start and got == 0:
                    raise PeerClosed(f"{self.peer} closed the connection")
                raise ProtocolError(f"{self.peer} closed the connection mid-frame")
            got += k
        return buf

    def recv(self) -> Frame:
        """Read one frame and verify magic, length, CRC, sequence number and version.

        Raises
        ------
        PeerClosed
            The peer closed the connection before the frame's first byte.
        ProtocolError
            Bad magic, oversized length, truncated frame, CRC mismatch,
            sequence gap or unknown frame type.
        ProtocolVersionError
            A frame other than ERROR with another protocol version.
        TimeoutError
            No byte within the socket's timeout.
        """
        header = self._read_exact(HEADER.size, frame_start=True)
        magic, version, ftype, seq, length = HEADER.unpack(header)
        if magic != MAGIC:
            raise ProtocolError(f"bad magic {bytes(magic)!r} in a frame header from {self.peer}")
        if length > MAX_PAYLOAD:
            raise ProtocolError(f"frame from {self.peer} announces {length} payload bytes "
                                f"(maximum {MAX_PAYLOAD})")
        body = self._read_exact(length + CRC.size, frame_start=False)
        view = memoryview(body)
        (crc,) = CRC.unpack_from(body, length)
        if zlib.crc32(view[:length], zlib.crc32(header)) != crc:
            kind = FrameType(ftype).name if ftype in _FRAME_TYPES else f"type {ftype}"
            raise ProtocolError(f"CRC mismatch in frame {seq} ({kind}) from {self.peer}")
        if seq != self._recv_seq:
            raise ProtocolError(f"sequence gap from {self.peer}: expected frame {self._recv_seq}, got {seq}")
        self._recv_seq = (self._recv_seq + 1) & 0xFFFFFFFF
        try:
            kind = FrameType(ftype)
        except ValueError:
            raise ProtocolError(f"unknown frame type {ftype} from {self.peer}") from None
        if version != PROTOCOL_VERSION and kind is not FrameType.ERROR:
            raise ProtocolVersionError(f"{self.peer} speaks protocol version {version}, "
                                       f"this end speaks version {PROTOCOL_VERSION}")
        return Frame(kind, version, seq, view[:length])

    def close(self) -> None:
        """Shut the connection down (wakes a thread blocked reading it) and close it."""
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass  # already closed by the peer
        self.sock.close()


# ---------------------------------------------------------------- messages


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=_F64)


def _expect_size(payload: memoryview, size: int, what: str) -> None:
    if payload.nbytes != size:
        raise ProtocolError(f"{what} payload is {payload.nbytes} bytes, expected {size}")


def encode_describe(description: BenchDescription) -> list:
    """Payload parts of DESCRIBE: the [motor] and [sensors] data, the limits and the back-EMF table."""
    m, cal, lim = description.motor, description.calibration, description.limits
    backemf = _f64(description.backemf_nm_per_a)
    if backemf.shape != (m.counts_per_rev, 3):
        raise BackendError(f"back-EMF table has shape {backemf.shape}, expected ({m.counts_per_rev}, 3)")
    head = _DESCRIBE_HEAD.pack(m.pole_pairs, m.slots, m.counts_per_rev, 0, m.inertia_kgm2,
                               *cal.current_scale, *cal.current_offset, cal.torque_gain,
                               lim.max_current_a, lim.max_torque_nm, lim.max_speed_hz)
    return [head, backemf]


def decode_describe(payload: memoryview) -> BenchDescription:
    """BenchDescription from a DESCRIBE payload."""
    if payload.nbytes < _DESCRIBE_HEAD.size:
        raise ProtocolError(f"DESCRIBE payload is {payload.nbytes} bytes, shorter than its "
                            f"{_DESCRIBE_HEAD.size}-byte head")
    pole_pairs, slots, cpr, _, inertia, *v = _DESCRIBE_HEAD.unpack_from(payload)
    _expect_size(payload, _DESCRIBE_HEAD.size + 24 * cpr, f"DESCRIBE (counts_per_rev = {cpr})")
    backemf = np.frombuffer(payload, _F64, 3 * cpr, _DESCRIBE_HEAD.size).reshape(cpr, 3).astype(float)
    return BenchDescription(
        motor=MotorInfo(pole_pairs, slots, cpr, inertia),
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
        parts = [_DATA_HEAD.pack(trial_id, flags, start, stop - start, 0), *(c[start:stop] for c in columns)]
        for p in parts:
            crc = zlib.crc32(p, crc)
        frames += 1
        yield FrameType.DATA, parts
    yield FrameType.END_OF_TRIAL, encode_end(EndOfTrial(trial_id, frames, trial.n_samples, crc))


class TrialAssembler:
    """Collects the DATA frames of one trial and verifies them against its END_OF_TRIAL.

    Parameters
    ----------
    trial_id : int
        The trial the frames must belong to.
    max_samples : int
        The most samples the target announced in ACCEPT.
    """

    def __init__(self, trial_id: int, max_samples: int) -> None:
        self.trial_id = trial_id
        self.max_samples = max_samples
        self.flags: Column | None = None
        self.n_samples = 0
        self.data_frames = 0
        self._crc = 0
        self._chunks: list[list[np.ndarray]] = []

    def add(self, payload: memoryview) -> None:
        """Decode one DATA payload; raise ProtocolError unless it continues this trial."""
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
        chunk, offset = [], _DATA_HEAD.size
        for (_, width, dtype, flag) in COLUMNS:
            if flag is None or flags & flag:
                array = np.frombuffer(payload, dtype, n * width, offset)
                chunk.append(array.reshape(n, 3) if width == 3 else array)
                offset += 8 * n * width
        self.flags = Column(flags)
        self._crc = zlib.crc32(payload, self._crc)
        self._chunks.append(chunk)
        self.n_samples += n
        self.data_frames += 1

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
        present = [(name, dtype) for name, _, dtype, flag in COLUMNS if flag is None or self.flags & flag]
        columns = {name: np.concatenate([c[i] for c in self._chunks]).astype(dtype.newbyteorder("="), copy=False)
                   for i, (name, dtype) in enumerate(present)}
        if np.any(np.diff(columns["count"]) <= 0):
            raise ProtocolError("trial data counts do not increase")
        return columns


# ---------------------------------------------------------------- requests a target accepts


def check_request(request: TrialRequest, description: BenchDescription) -> tuple[ErrorCode, str] | None:
    """Why a target described by ``description`` must refuse ``request``, or None.

    BAD_REQUEST: table lengths other than counts_per_rev, non-finite values,
    revolutions below 1, a seed outside 32 bits, a non-positive speed or
    calibration. LIMIT_EXCEEDED: speed above max_speed_hz, peak
    |set point + feed-forward + excitation| above max_torque_nm, or a peak
    current reference i*_p = tau_ref K_p / sum_q K_q^2 (the minimum-copper-loss
    references from the described back-EMF table) above max_current_a.
    """
    cpr = description.motor.counts_per_rev
    limits = description.limits
    for name in ("feedforward_nm", "excitation_nm"):
        table = np.asarray(getattr(request, name))
        if table.shape != (cpr,):
            return ErrorCode.BAD_REQUEST, f"{name} has shape {table.shape}, the target needs ({cpr},)"
        if not np.all(np.isfinite(table)):
            return ErrorCode.BAD_REQUEST, f"{name} holds NaN or infinite values"
    cal = request.calibration
    if not (np.all(cal.current_scale > 0) and np.all(np.isfinite(cal.current_scale))
            and np.all(np.isfinite(cal.current_offset)) and 0 < cal.torque_gain < np.inf):
        return ErrorCode.BAD_REQUEST, "calibration needs finite positive current scales and torque gain"
    if not 1 <= request.revolutions < 2**32:
        return ErrorCode.BAD_REQUEST, f"revolutions must be 1 to 2^32-1, got {request.revolutions}"
    if not 0 <= request.seed < 2**32:
        return ErrorCode.BAD_REQUEST, f"seed must be a 32-bit unsigned integer, got {request.seed}"
    if not np.isfinite(request.torque_setpoint_nm):
        return ErrorCode.BAD_REQUEST, f"torque set point must be finite, got {request.torque_setpoint_nm}"
    if not 0 < request.speed_setpoint_hz < np.inf:
        return ErrorCode.BAD_REQUEST, f"speed set point must be positive, got {request.speed_setpoint_hz} Hz"
    if request.speed_setpoint_hz > limits.max_speed_hz:
        return ErrorCode.LIMIT_EXCEEDED, (f"speed set point {request.speed_setpoint_hz:g} Hz exceeds "
                                          f"the bench limit of {limits.max_speed_hz:g} Hz")
    tau_ref = request.torque_reference_nm()
    k = int(np.argmax(np.abs(tau_ref)))
    if abs(tau_ref[k]) > limits.max_torque_nm:
        return ErrorCode.LIMIT_EXCEEDED, (f"torque reference {tau_ref[k]:.4g} N m at count {k} (set point + "
                                          f"feed-forward + excitation) exceeds the bench limit of "
                                          f"{limits.max_torque_nm:g} N m")
    i_ref = np.abs(current_references(tau_ref, description.backemf_nm_per_a))
    k, p = np.unravel_index(int(np.argmax(i_ref)), i_ref.shape)
    if i_ref[k, p] > limits.max_current_a:
        return ErrorCode.LIMIT_EXCEEDED, (f"current reference {i_ref[k, p]:.4g} A in phase {'abc'[p]} at count "
                                          f"{k} exceeds the bench limit of {limits.max_current_a:g} A")
    return None
