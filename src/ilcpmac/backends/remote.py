"""A real test bench (or its emulator) as a backend: the bench protocol over TCP.

`RemoteBackend` keeps one connection to the bench target, re-established as
needed. Nothing the target sends is trusted: a trial buffers at most what was
requested, must end by a deadline that heartbeats cannot extend, and every
sample is validated. A trial that fails in transit (connection lost, read
timeout, deadline passed, CRC error, sequence gap, incomplete, inconsistent
or invalid data) is run again from scratch on a new connection, up to
``retries`` times with exponential back-off; only a complete, verified trial
is ever returned. Requests beyond the target's limits are refused before
anything is sent. It reports the progress of a trial (`set_progress`) as its
samples arrive.
"""

from __future__ import annotations

import logging
import socket
import time
from typing import TYPE_CHECKING, Callable, TypeVar

import numpy as np

from ilcpmac.backends.base import BenchDescription, ProgressCallback, ProgressThrottle
from ilcpmac.backends.protocol import (
    Channel,
    ErrorCode,
    Frame,
    FrameTimeout,
    FrameType,
    ProtocolError,
    SampleBounds,
    TargetError,
    TrialAssembler,
    check_request,
    data_bound,
    decode_accept,
    decode_describe,
    decode_error,
    decode_heartbeat,
    encode_request,
)
from ilcpmac.core.errors import BackendError
from ilcpmac.core.records import TrialData, TrialRequest

if TYPE_CHECKING:
    from ilcpmac.backends.registry import BackendSetup

log = logging.getLogger(__name__)
T = TypeVar("T")
#: ERROR codes after which the trial is tried again (the others fail it at once)
_TRANSIENT = {ErrorCode.MALFORMED_FRAME, ErrorCode.UNEXPECTED_FRAME, ErrorCode.BUSY}
#: A trial attempt must end within this many times its recording time (revolutions / speed), plus the margin.
TRIAL_TIME_FACTOR = 2.0


def parse_address(address: str) -> tuple[str, int]:
    """(host, port) from ``"HOST:PORT"`` (an IPv6 host in brackets: ``"[::1]:5000"``)."""
    host, sep, port = address.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise BackendError(f"bench address {address!r} must be HOST:PORT with a port from 1 to 65535")
    return host, int(port)


def _same_description(a: BenchDescription, b: BenchDescription) -> bool:
    return (a.motor == b.motor and a.limits == b.limits
            and np.array_equal(a.backemf_nm_per_a, b.backemf_nm_per_a)
            and np.array_equal(a.calibration.current_scale, b.calibration.current_scale)
            and np.array_equal(a.calibration.current_offset, b.calibration.current_offset)
            and a.calibration.torque_gain == b.calibration.torque_gain)


class RemoteBackend:
    """Runs trials on a bench target that speaks the bench protocol (docs/protocol.md).

    Not thread-safe: one trial at a time (``max_parallel_trials`` 1). Use as a
    context manager, or call `close`, to release the connection.

    Parameters
    ----------
    address : str
        ``"HOST:PORT"`` of the target.
    connect_timeout_s : float
        Timeout of each connection attempt, s.
    read_timeout_s : float
        Timeout of every read, s: the longest silence accepted from the
        target. Keep it several times the target's heartbeat interval
        (HEARTBEAT_INTERVAL_S, 1 s). The handshake must also be complete
        within it.
    retries : int
        How many times a failed connection or trial is tried again.
    backoff_s : float
        Wait before the first retry, s; doubled before each further one.
    trial_margin_s : float
        Each trial attempt must end (END_OF_TRIAL) within TRIAL_TIME_FACTOR
        (2) x its recording time (revolutions / speed set point) plus this
        margin, s, from its REQUEST: the target's warm-up and transfer time.
    progress_interval_s : float
        Shortest time between two progress reports of a trial (`set_progress`), s.
    """

    max_parallel_trials = 1

    def __init__(self, address: str, connect_timeout_s: float = 5.0, read_timeout_s: float = 10.0,
                 retries: int = 3, backoff_s: float = 0.5, trial_margin_s: float = 20.0,
                 progress_interval_s: float = 0.1) -> None:
        if (min(connect_timeout_s, read_timeout_s, trial_margin_s) <= 0 or retries < 0 or backoff_s < 0
                or progress_interval_s < 0):
            raise BackendError("remote backend needs positive timeouts and margin, and non-negative retries, "
                               "back-off and progress interval")
        self.address = address
        self.host, self.port = parse_address(address)
        self.connect_timeout_s = connect_timeout_s
        self.read_timeout_s = read_timeout_s
        self.retries = retries
        self.backoff_s = backoff_s
        self.trial_margin_s = trial_margin_s
        self.progress_interval_s = progress_interval_s
        self._progress: ProgressCallback | None = None
        self._channel: Channel | None = None
        self._description: BenchDescription | None = None
        self._trials = 0
        self._next_trial_id = 1

    @classmethod
    def from_setup(cls, setup: BackendSetup) -> RemoteBackend:
        """A bench target speaking the bench protocol over TCP at --address HOST:PORT (docs/protocol.md)."""
        setup.refuse_options("remote")
        if not setup.address:
            raise BackendError("--backend remote needs --address HOST:PORT")
        return cls(setup.address)

    # -------------------------------------------------------- connection

    def _connect(self) -> Channel:
        """The open channel, connecting and shaking hands first if there is none (or the target closed it)."""
        if self._channel is not None and self._channel.peer_closed():
            self.close()  # e.g. the target's idle timeout: reconnect without counting a failure
        if self._channel is not None:
            return self._channel
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        try:
            sock.settimeout(self.read_timeout_s)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            channel = Channel(sock, f"bench target {self.address}")
            channel.send(FrameType.HELLO)
            frame = channel.recv(deadline=time.monotonic() + self.read_timeout_s)
            if frame.type is FrameType.ERROR:
                raise decode_error(frame.payload)
            if frame.type is not FrameType.DESCRIBE:
                raise ProtocolError(f"target answered HELLO with {frame.type.name}, expected DESCRIBE")
            description = decode_describe(frame.payload)
        except BaseException:
            sock.close()
            raise
        if self._description is None:
            self._description = description
        elif not _same_description(description, self._description):
            channel.close()
            raise BackendError(f"bench target {self.address} describes another motor, calibration or limits "
                               "after reconnecting: refusing to mix its trials with earlier ones")
        self._channel = channel
        return channel

    def close(self) -> None:
        """Close the connection (the next call reconnects)."""
        if self._channel is not None:
            self._channel.close()
            self._channel = None

    def __enter__(self) -> RemoteBackend:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _with_retries(self, what: str, attempt: Callable[[], T], level: int = logging.WARNING) -> T:
        """Call ``attempt()`` until it succeeds, retrying transport failures with back-off; each failed attempt
        logged at ``level``, the last failure raised in one line."""
        tries = self.retries + 1
        for k in range(tries):
            if k:
                time.sleep(self.backoff_s * 2 ** (k - 1))
            try:
                return attempt()
            except BackendError as e:
                self.close()
                transient = isinstance(e, TargetError) and e.code in _TRANSIENT
                if not (transient or isinstance(e, ProtocolError)):
                    raise BackendError(f"{what} on {self.address}: {e}") from None
                last: Exception = e
            except OSError as e:
                self.close()
                last = e
            log.log(level, "%s on %s: attempt %d of %d failed (%s)", what, self.address, k + 1, tries,
                    self._reason(last))
        raise BackendError(f"{what} on {self.address}: gave up after {tries} attempts; "
                           f"last failure: {self._reason(last)}") from None

    def _reason(self, error: Exception) -> str:
        if isinstance(error, TimeoutError):
            return (f"timed out waiting for the target (connect timeout {self.connect_timeout_s:g} s, "
                    f"read timeout {self.read_timeout_s:g} s)")
        if isinstance(error, OSError):
            return f"{type(error).__name__}: {error.strerror or error}"
        return str(error)

    # -------------------------------------------------------- Backend

    def describe(self) -> BenchDescription:
        """The target's motor, back-EMF table, calibration and limits (from the handshake).

        Its attempts are logged at INFO only: a handshake that fails (no bench at the address, a closed port, a
        server that speaks something else or nothing) is the error's one line, and one that succeeds after a
        retry (a bench booting) needs no warning."""
        if self._description is None:
            self._with_retries("handshake with the bench target", self._connect, logging.INFO)
        assert self._description is not None, "a successful handshake records the description"
        return self._description

    def set_progress(self, callback: ProgressCallback | None) -> None:
        """Report the progress of every later trial to ``callback`` (None: stop), at most once per
        ``progress_interval_s``: the samples received over the samples ACCEPT announced (revolutions x
        counts_per_rev). 0 at each ACCEPT, and while the target warms up (its warm-up is not recorded, so
        no sample arrives); 1 once the trial is complete and verified. A retried trial starts again from 0."""
        self._progress = None if callback is None else ProgressThrottle(callback, self.progress_interval_s)

    def run_trial(self, request: TrialRequest) -> TrialData:
        """Run one trial on the target; return it only complete and verified.

        Raises
        ------
        BackendError
            The request is beyond the target's limits (nothing is sent), the
            target refused it or reported a failed trial, it speaks another
            protocol version, or every attempt failed in transit. The message
            names the trial and what failed.
        """
        self._trials += 1
        what = (f"trial {self._trials} ({request.torque_setpoint_nm:g} N m, "
                f"{request.speed_setpoint_hz:g} Hz)")
        refusal = check_request(request, self.describe())
        if refusal is not None:
            raise BackendError(f"{what}: refused before sending ({refusal[0].name}): {refusal[1]}")
        return self._with_retries(what, lambda: self._attempt(request))

    def _attempt(self, request: TrialRequest) -> TrialData:
        channel = self._connect()
        description = self.describe()
        bounds = SampleBounds.of(request, description)
        recording_s = request.revolutions / request.speed_setpoint_hz
        budget_s = TRIAL_TIME_FACTOR * recording_s + self.trial_margin_s
        trial_id = self._next_trial_id
        self._next_trial_id = self._next_trial_id % 0xFFFFFFFF + 1
        channel.send(FrameType.REQUEST, encode_request(trial_id, request))
        deadline = time.monotonic() + budget_s
        try:
            frame = self._next(channel, trial_id, deadline)
            if frame.type is not FrameType.ACCEPT:
                raise ProtocolError(f"target answered REQUEST with {frame.type.name}, expected ACCEPT")
            accept = decode_accept(frame.payload)
            if accept.trial_id != trial_id:
                raise ProtocolError(f"ACCEPT of trial {accept.trial_id}, expected trial {trial_id}")
            if accept.max_samples > bounds.max_samples:
                raise ProtocolError(f"ACCEPT announces {accept.max_samples} samples, the request asks for "
                                    f"{bounds.max_samples} (revolutions x counts_per_rev)")
            channel.bounds[FrameType.DATA] = data_bound(accept.max_samples)
            assembler = TrialAssembler(trial_id, accept.max_samples, bounds)
            self._report(0.0)
            while (frame := self._next(channel, trial_id, deadline)).type is FrameType.DATA:
                assembler.add(frame.payload)
                self._report(assembler.n_samples / accept.max_samples)
        except FrameTimeout:
            raise ProtocolError(f"trial not complete within its deadline of {budget_s:.4g} s "
                                f"({TRIAL_TIME_FACTOR:g} x {recording_s:.4g} s of recording + "
                                f"{self.trial_margin_s:g} s margin)") from None
        if frame.type is not FrameType.END_OF_TRIAL:
            raise ProtocolError(f"unexpected {frame.type.name} frame during trial data")
        columns = assembler.finish(frame.payload)
        torque = columns.pop("torque_nm")  # meaningless from a bench without a torque sensor
        self._report(1.0)
        return TrialData(torque_setpoint_nm=request.torque_setpoint_nm,
                         speed_setpoint_hz=request.speed_setpoint_hz, request=request,
                         torque_nm=torque if description.motor.torque_sensor else None, **columns)

    def _report(self, fraction: float) -> None:
        if self._progress is not None:
            self._progress(fraction)

    def _next(self, channel: Channel, trial_id: int, deadline: float) -> Frame:
        """The next frame of trial ``trial_id`` other than HEARTBEAT, complete by ``deadline``
        (time.monotonic); ERROR frames are raised."""
        while True:
            frame = channel.recv(deadline)
            if frame.type is FrameType.ERROR:
                raise decode_error(frame.payload)
            if frame.type is not FrameType.HEARTBEAT:
                return frame
            if decode_heartbeat(frame.payload) != trial_id:
                raise ProtocolError(f"HEARTBEAT of another trial during trial {trial_id}")
