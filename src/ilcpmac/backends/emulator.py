"""A bench target emulator: serves a backend (the numba simulator) over the bench protocol.

For tests, and for developing target firmware against: it speaks exactly
docs/protocol.md, and can inject the faults a client must survive (a
connection dropped mid-trial, a stall, a corrupted frame, a wrong protocol
version, a restart of the target), each on a chosen trial so that tests are
deterministic. It can play each trial back at the pace of a bench (``pace``),
its DATA frames spread over the trial's time, so that a client sees the
trial progress. Like a real bench it has one controlling client at a time
(another gets ERROR BUSY), a bounded number of connections, bounded frames,
and drops idle or slow clients; a connection still before its HELLO gives its
slot up to a newcomer, so that half-open clients cannot lock the others out.
Whatever the backend raises is answered with an ERROR, and it keeps serving.
"""

from __future__ import annotations

import itertools
import logging
import os
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, fields
from typing import Iterator

import numpy as np

from ilcpmac.backends.base import Backend
from ilcpmac.backends.protocol import (
    CRC,
    HEADER,
    HEARTBEAT_INTERVAL_S,
    PROTOCOL_VERSION,
    Accept,
    Channel,
    ErrorCode,
    FrameTimeout,
    FrameType,
    PeerClosed,
    ProtocolError,
    ProtocolVersionError,
    check_request,
    check_servable,
    check_trial_id,
    decode_request,
    encode_accept,
    encode_describe,
    encode_error,
    encode_heartbeat,
    encode_trial,
    target_bounds,
)
from ilcpmac.bench.format import MAX_TRIAL_ROWS
from ilcpmac.core.errors import BackendError, IlcpmacError
from ilcpmac.core.records import TrialRequest

log = logging.getLogger(__name__)

#: How often the accept loop looks for a stop or restart, s.
_POLL_S = 0.1


@dataclass(frozen=True)
class Fault:
    """When a fault fires: on trial ``trial`` (the emulator's 1-based count of
    REQUEST frames received, retries included), and with ``repeat`` on every later one too."""

    trial: int
    repeat: bool = False

    def __post_init__(self) -> None:
        if self.trial < 1:
            raise BackendError(f"a fault fires on trial 1 or later, got {self.trial}")

    @classmethod
    def parse(cls, text: str) -> Fault:
        """``"N"``: trial N only; ``"N+"``: trial N and every later one."""
        number = text.removesuffix("+")
        if not number.isdigit():
            raise BackendError(f"fault trial {text!r} must be N (trial N only) or N+ (trial N and later)")
        return cls(int(number), repeat=text.endswith("+"))

    def fires(self, trial: int) -> bool:
        """Whether the fault fires on trial number ``trial``."""
        return trial == self.trial or (self.repeat and trial > self.trial)


@dataclass(frozen=True)
class FaultPlan:
    """The faults an emulator injects; None = never.

    Attributes
    ----------
    drop : Fault or None
        Close the connection after the trial's first DATA frame.
    stall : Fault or None
        Send nothing for ``stall_s`` after the trial's first DATA frame
        (no heartbeats either), then go on.
    corrupt : Fault or None
        Flip one payload byte of the trial's first DATA frame (after its CRC).
    wrong_version : Fault or None
        Answer the request with frames of protocol version PROTOCOL_VERSION + 1.
    restart : Fault or None
        After the trial's first DATA frame, act as a rebooting target: close
        every connection and the listening socket, forget all connection
        state, and listen again on the same port after ``restart_delay_s``.
        (The trial counter that times faults survives.)
    stall_s : float
        Length of a stall, s.
    """

    drop: Fault | None = None
    stall: Fault | None = None
    corrupt: Fault | None = None
    wrong_version: Fault | None = None
    restart: Fault | None = None
    stall_s: float = 30.0

    def active(self, trial: int) -> set[str]:
        """Names of the faults that fire on trial number ``trial``."""
        return {f.name for f in fields(self)
                if isinstance(getattr(self, f.name), Fault) and getattr(self, f.name).fires(trial)}


class BenchEmulator:
    """A bench target on TCP serving ``backend`` over the bench protocol, one thread per connection.

    Start with `start` (or ``with``), stop with `stop`; ``port=0`` picks a
    free port, read back from `port` / `address`.

    Parameters
    ----------
    backend : Backend
        What runs the trials (a `SimulatorBackend`); its ``describe()`` is
        the handshake's DESCRIBE, its limits are enforced.
    host : str
        Address to listen on.
    port : int
        Port to listen on, 0 for any free one.
    faults : FaultPlan
        Faults to inject.
    chunk_samples : int
        Samples per DATA frame.
    pace : float or None
        None: send each trial's frames as fast as the client takes them, once it has run. Otherwise play
        the trial back at ``pace`` times the bench's speed (1: as a bench records it): each DATA frame
        leaves once its last sample's time stamp (s from the trial's start: the simulator's count its
        warm-up too) divided by ``pace`` has passed since the REQUEST, with HEARTBEATs in between.
    heartbeat_s : float
        HEARTBEAT interval while a trial runs, s.
    restart_delay_s : float
        How long a restarting target stays unreachable, s.
    idle_timeout_s : float
        A client that sends no frame for this long (before its HELLO or
        between trials) is disconnected, s.
    frame_timeout_s : float
        A frame must arrive complete within this many seconds of its first
        byte, and the client must take each frame sent to it within it;
        otherwise it is disconnected.
    max_connections : int
        Connections open at once. When all are open, a new connection takes the slot of the oldest one
        that has not sent its HELLO yet (which is closed); with none such, it is answered ERROR BUSY and
        closed.
    max_trial_samples : int
        Largest trial (revolutions x counts_per_rev) run; a larger request
        is refused with LIMIT_EXCEEDED.
    """

    def __init__(self, backend: Backend, host: str = "127.0.0.1", port: int = 0, faults: FaultPlan = FaultPlan(),
                 chunk_samples: int = 8192, pace: float | None = None, heartbeat_s: float = HEARTBEAT_INTERVAL_S,
                 restart_delay_s: float = 0.5, idle_timeout_s: float = 20.0, frame_timeout_s: float = 10.0,
                 max_connections: int = 4, max_trial_samples: int = MAX_TRIAL_ROWS) -> None:
        if (chunk_samples < 1 or not (pace is None or 0 < pace < float("inf")) or heartbeat_s <= 0
                or restart_delay_s < 0 or idle_timeout_s <= 0 or frame_timeout_s <= 0 or max_connections < 1
                or max_trial_samples < 2):
            raise BackendError("emulator needs chunk_samples >= 1, pace None or positive and finite, "
                               "heartbeat_s, idle_timeout_s and frame_timeout_s > 0, restart_delay_s >= 0, "
                               "max_connections >= 1 and max_trial_samples >= 2")
        self.backend = backend
        self._description = backend.describe()
        check_servable(self._description)
        self.host = host
        self.port = port
        self.faults = faults
        self.chunk_samples = chunk_samples
        self.pace = pace
        self.heartbeat_s = heartbeat_s
        self.restart_delay_s = restart_delay_s
        self.idle_timeout_s = idle_timeout_s
        self.frame_timeout_s = frame_timeout_s
        self.max_connections = max_connections
        self.max_trial_samples = max_trial_samples
        #: (fault name, trial number) of every fault fired, in order
        self.faults_fired: list[tuple[str, int]] = []
        self._requests = 0
        self._lock = threading.Lock()
        self._restart_lock = threading.Lock()
        self._stopping = threading.Event()
        self._generation = 0
        self._channels: set[Channel] = set()
        #: the open connections whose HELLO has not arrived, oldest first (a dict as an ordered set)
        self._handshaking: dict[Channel, None] = {}
        self._controller: Channel | None = None
        self._threads: set[threading.Thread] = set()
        self._accept_thread: threading.Thread | None = None
        self._pool: ThreadPoolExecutor | None = None

    @property
    def address(self) -> str:
        """``"HOST:PORT"`` as a client connects to it."""
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"

    @property
    def requests_received(self) -> int:
        """REQUEST frames received so far (the trial count that times faults)."""
        return self._requests

    # -------------------------------------------------------- life cycle

    def start(self) -> BenchEmulator:
        """Listen and serve in background threads; return self."""
        self._pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="emulator-trial")
        self._listen()
        log.info("bench emulator listening on %s (protocol version %d)", self.address, PROTOCOL_VERSION)
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close every connection and the listening socket; wait for the threads to end."""
        self._stopping.set()
        if self._accept_thread is not None:
            self._accept_thread.join(timeout_s)  # no connection is accepted after this
        with self._lock:
            channels = list(self._channels)
            threads = list(self._threads)
        for channel in channels:
            channel.shutdown()  # its thread closes it
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join(timeout_s)
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> BenchEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _listen(self) -> None:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        try:
            listener = socket.create_server((self.host, self.port), family=family)
        except OSError as e:
            raise BackendError(f"emulator cannot listen on {self.address}: {e.strerror or e}") from None
        listener.settimeout(_POLL_S)
        self.port = listener.getsockname()[1]
        thread = threading.Thread(target=self._accept_loop, args=(listener, self._generation),
                                  name="emulator-accept", daemon=True)
        with self._lock:
            self._accept_thread = thread
        thread.start()

    def _accept_loop(self, listener: socket.socket, generation: int) -> None:
        with listener:
            while not self._stopping.is_set() and generation == self._generation:
                try:
                    conn, peer = listener.accept()
                except TimeoutError:
                    continue
                conn.settimeout(self.idle_timeout_s)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                channel = Channel(conn, f"client {peer[0]}:{peer[1]}",
                                  target_bounds(self._description.motor.counts_per_rev), self.frame_timeout_s)
                thread = threading.Thread(target=self._serve, args=(channel,), name="emulator-client",
                                          daemon=True)
                with self._lock:
                    evicted = None
                    if len(self._channels) >= self.max_connections and self._handshaking:
                        evicted = next(iter(self._handshaking))
                        del self._handshaking[evicted]
                        self._channels.discard(evicted)
                    full = len(self._channels) >= self.max_connections
                    if not full:
                        self._channels.add(channel)
                        self._handshaking[channel] = None
                        self._threads.add(thread)
                if evicted is not None:
                    log.warning("%s dropped before its HELLO: %s needs its slot", evicted.peer, channel.peer)
                    evicted.shutdown()  # its thread closes it
                if full:
                    log.warning("%s refused: %d connections open", channel.peer, self.max_connections)
                    self._send_error(channel, ErrorCode.BUSY, 0,
                                     f"all {self.max_connections} connections this target serves are past their "
                                     "HELLO")
                    channel.close()
                    continue
                thread.start()

    def _restart(self) -> None:
        """Act as a rebooting target (see FaultPlan.restart)."""
        with self._restart_lock:
            with self._lock:
                self._generation += 1
                self._controller = None
                channels = list(self._channels)
                old = self._accept_thread
            for channel in channels:
                channel.shutdown()  # its thread closes it
            if old is not None:
                old.join()
            if not self._stopping.wait(self.restart_delay_s):
                self._listen()
                log.info("bench emulator restarted on %s", self.address)

    # -------------------------------------------------------- one client

    def _take_control(self, channel: Channel) -> bool:
        """Make ``channel``, whose HELLO has arrived, the controlling client, unless another one is still
        connected; either way no newcomer takes its slot any more."""
        with self._lock:
            self._handshaking.pop(channel, None)
            current = self._controller
            if current is not None and not current.peer_closed():
                return False
            if current is not None:
                current.shutdown()  # its client has gone: wake its thread, which closes it
            self._controller = channel
            return True

    def _serve(self, channel: Channel) -> None:
        log.info("%s connected", channel.peer)
        try:
            expected = FrameType.HELLO
            if (frame := channel.recv()).type is FrameType.HELLO:
                if not self._take_control(channel):
                    self._send_error(channel, ErrorCode.BUSY, 0, "another client controls this bench target")
                    return
                channel.send(FrameType.DESCRIBE, encode_describe(self._description))
                expected = FrameType.REQUEST
                while (frame := channel.recv()).type is FrameType.REQUEST:
                    if not self._trial(channel, frame.payload):
                        return
            if frame.type is not FrameType.ERROR:  # a client's ERROR just ends the connection
                self._send_error(channel, ErrorCode.UNEXPECTED_FRAME, 0,
                                 f"expected {expected.name}, got {frame.type.name}")
        except PeerClosed:
            pass
        except FrameTimeout as e:
            log.info("%s: dropped (%s)", channel.peer, e)
        except TimeoutError:
            log.info("%s: dropped after %g s without a frame", channel.peer, self.idle_timeout_s)
        except ProtocolVersionError:
            self._send_error(channel, ErrorCode.VERSION_MISMATCH, 0,
                             f"this target speaks protocol version {PROTOCOL_VERSION}")
        except ProtocolError as e:
            self._send_error(channel, ErrorCode.MALFORMED_FRAME, 0, str(e))
        except OSError:
            pass  # the client went away, or stop/restart closed the connection
        except Exception as e:  # a bug in the target: tell the client, keep serving the next one
            log.exception("%s: internal error", channel.peer)
            self._send_error(channel, ErrorCode.INTERNAL, 0, f"{type(e).__name__}: {e}")
        finally:
            with self._lock:
                if self._controller is channel:
                    self._controller = None
                self._channels.discard(channel)
                self._handshaking.pop(channel, None)
                self._threads.discard(threading.current_thread())
            channel.close()
            log.info("%s disconnected", channel.peer)

    @staticmethod
    def _send_error(channel: Channel, code: ErrorCode, trial_id: int, message: str) -> None:
        try:
            channel.send(FrameType.ERROR, encode_error(code, trial_id, message))
        except (OSError, FrameTimeout):
            pass  # the connection is gone or stuck: nobody to tell

    def _trial(self, channel: Channel, payload: memoryview) -> bool:
        """Serve one REQUEST; False when the connection must end (a fault fired, or the emulator stops)."""
        trial_id, request = decode_request(payload)
        with self._lock:
            self._requests += 1
            number = self._requests
        max_samples = request.revolutions * self._description.motor.counts_per_rev
        refusal = check_trial_id(trial_id) or check_request(request, self._description)
        if refusal is None and max_samples > self.max_trial_samples:
            refusal = (ErrorCode.LIMIT_EXCEEDED, f"{max_samples} samples (revolutions x counts_per_rev) exceed "
                                                 f"the {self.max_trial_samples} this target records per trial")
        if refusal is not None:
            self._send_error(channel, refusal[0], trial_id, refusal[1])
            return True
        faults = self.faults.active(number)
        for name in sorted(faults):
            log.warning("fault on trial %d: %s", number, name)
            with self._lock:
                self.faults_fired.append((name, number))
        version = PROTOCOL_VERSION + 1 if "wrong_version" in faults else PROTOCOL_VERSION
        accept = encode_accept(Accept(trial_id, max_samples))
        started = time.monotonic()
        assert self._pool is not None, "start() made the pool before any connection"
        future = self._pool.submit(self._run, trial_id, request, max_samples)
        # ACCEPT waits one heartbeat interval: a request the backend refuses at once gets an ERROR alone
        accepted = False
        while True:
            try:
                frames, ready_s = future.result(timeout=self.heartbeat_s)
                break
            except FutureTimeout:
                channel.send_bytes(channel.frame_bytes(FrameType.HEARTBEAT, encode_heartbeat(trial_id), version)
                                   if accepted else channel.frame_bytes(FrameType.ACCEPT, accept, version))
                accepted = True
            except IlcpmacError as e:
                self._send_error(channel, ErrorCode.TRIAL_FAILED, trial_id, str(e))
                return True
            except Exception as e:  # a bug in the backend: report it to the client, keep serving
                log.exception("trial %d failed", number)
                self._send_error(channel, ErrorCode.INTERNAL, trial_id, f"{type(e).__name__}: {e}")
                return True
        if not accepted:
            channel.send_bytes(channel.frame_bytes(FrameType.ACCEPT, accept, version))
        for i, ((ftype, parts), at_s) in enumerate(zip(frames, ready_s)):
            if self.pace is not None and not self._wait(channel, started + at_s / self.pace, trial_id, version):
                return False
            frame = channel.frame_bytes(ftype, parts, version)
            if i == 0 and "corrupt" in faults:
                frame[HEADER.size + (len(frame) - HEADER.size - CRC.size) // 2] ^= 0xFF
            channel.send_bytes(frame)
            if i == 0:
                if "restart" in faults:
                    self._restart()
                    return False
                if "drop" in faults:
                    return False
                if "stall" in faults:
                    self._stopping.wait(self.faults.stall_s)
        return True

    def _wait(self, channel: Channel, due: float, trial_id: int, version: int) -> bool:
        """Send a HEARTBEAT every ``heartbeat_s`` until ``due`` (time.monotonic); False if the emulator stops."""
        while (remaining := due - time.monotonic()) > 0:
            if self._stopping.wait(min(remaining, self.heartbeat_s)):
                return False
            if time.monotonic() < due:
                channel.send_bytes(channel.frame_bytes(FrameType.HEARTBEAT, encode_heartbeat(trial_id), version))
        return True

    def _run(self, trial_id: int, request: TrialRequest,
             max_samples: int) -> tuple[Iterator[tuple[FrameType, list]], np.ndarray]:
        """Run ``request`` on the backend; the (type, parts) of its DATA frames and END_OF_TRIAL, and when
        each is ready: the time stamp of its last sample, s."""
        data = self.backend.run_trial(request)
        n = data.n_samples
        if not 2 <= n <= max_samples:
            raise BackendError(f"the backend returned {n} samples for a trial of 2 to {max_samples} samples")
        frames = encode_trial(trial_id, data, self.chunk_samples)
        ends = np.minimum(np.arange(self.chunk_samples, n + self.chunk_samples, self.chunk_samples), n)
        ready_s = data.time_s[np.append(ends, n) - 1]
        return itertools.chain([next(frames)], frames), ready_s  # the first frame checks every column's shape
