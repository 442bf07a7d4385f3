"""A bench target emulator: serves a backend (the numba simulator) over the bench protocol.

For tests, and for developing target firmware against: it speaks exactly
docs/protocol.md, and can inject the faults a client must survive (a
connection dropped mid-trial, a stall, a corrupted frame, a wrong protocol
version, a restart of the target), each on a chosen trial so that tests are
deterministic.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, fields

from ilcpmac.backends.base import Backend
from ilcpmac.backends.protocol import (
    CRC,
    HEADER,
    HEARTBEAT_INTERVAL_S,
    PROTOCOL_VERSION,
    Accept,
    Channel,
    ErrorCode,
    FrameType,
    PeerClosed,
    ProtocolError,
    ProtocolVersionError,
    check_request,
    decode_request,
    encode_accept,
    encode_describe,
    encode_error,
    encode_heartbeat,
    encode_trial,
)
from ilcpmac.errors import BackendError, IlcpmacError

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
    """A bench target on TCP serving ``backend`` over the bench protocol, one thread per client.

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
    heartbeat_s : float
        HEARTBEAT interval while a trial runs, s.
    restart_delay_s : float
        How long a restarting target stays unreachable, s.
    """

    def __init__(self, backend: Backend, host: str = "127.0.0.1", port: int = 0, faults: FaultPlan = FaultPlan(),
                 chunk_samples: int = 8192, heartbeat_s: float = HEARTBEAT_INTERVAL_S,
                 restart_delay_s: float = 0.5) -> None:
        if chunk_samples < 1 or heartbeat_s <= 0 or restart_delay_s < 0:
            raise BackendError("emulator needs chunk_samples >= 1, heartbeat_s > 0 and restart_delay_s >= 0")
        self.backend = backend
        self._description = backend.describe()
        self.host = host
        self.port = port
        self.faults = faults
        self.chunk_samples = chunk_samples
        self.heartbeat_s = heartbeat_s
        self.restart_delay_s = restart_delay_s
        #: (fault name, trial number) of every fault fired, in order
        self.faults_fired: list[tuple[str, int]] = []
        self._requests = 0
        self._lock = threading.Lock()
        self._restart_lock = threading.Lock()
        self._stopping = threading.Event()
        self._generation = 0
        self._channels: set[Channel] = set()
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
            channel.close()
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
                conn.settimeout(None)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                channel = Channel(conn, f"client {peer[0]}:{peer[1]}")
                thread = threading.Thread(target=self._serve, args=(channel,), name="emulator-client",
                                          daemon=True)
                with self._lock:
                    self._channels.add(channel)
                    self._threads.add(thread)
                thread.start()

    def _restart(self) -> None:
        """Act as a rebooting target (see FaultPlan.restart)."""
        with self._restart_lock:
            with self._lock:
                self._generation += 1
                channels = list(self._channels)
                old = self._accept_thread
            for channel in channels:
                channel.close()
            if old is not None:
                old.join()
            if not self._stopping.wait(self.restart_delay_s):
                self._listen()
                log.info("bench emulator restarted on %s", self.address)

    # -------------------------------------------------------- one client

    def _serve(self, channel: Channel) -> None:
        log.info("%s connected", channel.peer)
        try:
            expected = FrameType.HELLO
            if (frame := channel.recv()).type is FrameType.HELLO:
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
        except ProtocolVersionError:
            self._send_error(channel, ErrorCode.VERSION_MISMATCH, 0,
                             f"this target speaks protocol version {PROTOCOL_VERSION}")
        except ProtocolError as e:
            self._send_error(channel, ErrorCode.MALFORMED_FRAME, 0, str(e))
        except OSError:
            pass  # the client went away, or stop/restart closed the connection
        finally:
            channel.close()
            with self._lock:
                self._channels.discard(channel)
                self._threads.discard(threading.current_thread())
            log.info("%s disconnected", channel.peer)

    @staticmethod
    def _send_error(channel: Channel, code: ErrorCode, trial_id: int, message: str) -> None:
        try:
            channel.send(FrameType.ERROR, encode_error(code, trial_id, message))
        except OSError:
            pass  # the connection is gone: nobody to tell

    def _trial(self, channel: Channel, payload: memoryview) -> bool:
        """Serve one REQUEST; False when the connection must end (a fault fired)."""
        trial_id, request = decode_request(payload)
        with self._lock:
            self._requests += 1
            number = self._requests
        refusal = check_request(request, self._description)
        if refusal is not None:
            self._send_error(channel, refusal[0], trial_id, refusal[1])
            return True
        faults = self.faults.active(number)
        for name in sorted(faults):
            log.warning("fault on trial %d: %s", number, name)
            with self._lock:
                self.faults_fired.append((name, number))
        version = PROTOCOL_VERSION + 1 if "wrong_version" in faults else PROTOCOL_VERSION
        max_samples = request.revolutions * self._description.motor.counts_per_rev
        channel.send_bytes(channel.frame_bytes(FrameType.ACCEPT, encode_accept(Accept(trial_id, max_samples)),
                                               version))
        future = self._pool.submit(self.backend.run_trial, request)
        while True:
            try:
                data = future.result(timeout=self.heartbeat_s)
                break
            except FutureTimeout:
                channel.send_bytes(channel.frame_bytes(FrameType.HEARTBEAT, encode_heartbeat(trial_id), version))
            except IlcpmacError as e:
                self._send_error(channel, ErrorCode.TRIAL_FAILED, trial_id, str(e))
                return True
            except Exception as e:  # a bug in the backend: report it to the client, keep serving
                log.exception("trial %d failed", number)
                self._send_error(channel, ErrorCode.INTERNAL, trial_id, f"{type(e).__name__}: {e}")
                return True
        for i, (ftype, parts) in enumerate(encode_trial(trial_id, data, self.chunk_samples)):
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
