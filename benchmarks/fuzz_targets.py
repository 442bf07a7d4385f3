"""The protocol half of ``benchmarks/fuzz.py``: hostile bench targets, hostile clients, and the client driver.

Both directions of the bench protocol (docs/protocol.md) are attacked:

- `TARGETS`: misbehaving bench targets (`HostileTarget` serves one of them on
  127.0.0.1) answering ilcpmac's `RemoteBackend`, which runs in a subprocess
  (``python benchmarks/fuzz_targets.py client HOST:PORT OUT.json``, this
  file's `client_main`) or as ``ilcpmac run --backend remote``;
- `ATTACKS`: hostile clients against ``ilcpmac emulate`` (`Emulator` runs it
  as a subprocess); after each one a well-formed client must still get its
  DESCRIBE.

Frames are built here from the specification's layouts (not with the
package's encoders, which may refuse to encode the garbage sent), framed and
CRC-sealed by `Wire`.
"""

from __future__ import annotations

import json
import os
import re
import resource
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ilcpmac.backends.protocol import CRC, HEADER, MAGIC, MAX_PAYLOAD, ErrorCode, FrameType

DESCRIBE_HEAD = struct.Struct("<IIII11d")
REQUEST_HEAD = struct.Struct("<IIII9d")
ACCEPT = struct.Struct("<IIQ")
DATA_HEAD = struct.Struct("<IIQII")
END = struct.Struct("<IIQII")
HEARTBEAT = struct.Struct("<II")
ERROR_HEAD = struct.Struct("<II")

#: the small drive every hostile target describes (the fuzz's small config: 4096 counts, 8 pole pairs)
COUNTS_PER_REV = 4096
POLE_PAIRS = 8
#: limits an honest target announces: max current A, max torque N m, max speed Hz
LIMITS = (30.0, 8.0, 1.5)
#: how long an attack waits for the emulator to answer or close, s
ANSWER_S = 3.0
#: an idle or half-sent connection must be closed by the emulator within this, s
IDLE_CLOSE_S = 30.0
#: more simultaneous sessions than this (DESCRIBE answered at once) is accepting garbage
MAX_SESSIONS = 8


# ---------------------------------------------------------------- framing


class Wire:
    """One end of a connection: numbers its frames, seals them, reads the peer's."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.seq = 0

    def frame(self, ftype: int, payload: bytes = b"", version: int = 1, seq: int | None = None) -> bytes:
        """A sealed frame (the next sequence number unless ``seq`` is given)."""
        head = HEADER.pack(MAGIC, version, ftype, self.seq if seq is None else seq, len(payload))
        self.seq += seq is None
        return head + payload + CRC.pack(zlib.crc32(payload, zlib.crc32(head)))

    def send(self, ftype: int, payload: bytes = b"", version: int = 1) -> None:
        self.sock.sendall(self.frame(ftype, payload, version))

    def recv(self) -> tuple[int, bytes] | None:
        """(type, payload) of the next frame; None when the peer closed. No checks: a hostile end trusts nothing."""
        head = _read(self.sock, HEADER.size)
        if head is None:
            return None
        _, _, ftype, _, length = HEADER.unpack(head)
        body = _read(self.sock, min(length, MAX_PAYLOAD) + CRC.size)
        return None if body is None else (ftype, body[:-CRC.size])


def _read(sock: socket.socket, n: int) -> bytes | None:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


# ---------------------------------------------------------------- payloads


def backemf_table(cpr: int = COUNTS_PER_REV) -> np.ndarray:
    theta = 2 * np.pi * np.arange(cpr) / cpr
    return 0.2 * np.sin(POLE_PAIRS * theta[:, None] - 2 * np.pi * np.arange(3) / 3)


def describe_payload(cpr: int = COUNTS_PER_REV, inertia: float = 0.01056, limits=LIMITS, backemf=None,
                     pole_pairs: int = POLE_PAIRS, table_rows: int | None = None) -> bytes:
    """DESCRIBE with the given fields; ``table_rows`` back-EMF rows (default ``cpr``)."""
    table = backemf_table(cpr if table_rows is None else table_rows) if backemf is None else backemf
    head = DESCRIBE_HEAD.pack(pole_pairs, 48, cpr, 0, inertia, 14.0, 14.0, 14.0, 0.0, 0.0, 0.0, 0.908, *limits)
    return head + np.ascontiguousarray(table, "<f8").tobytes()


def request_payload(trial_id: int = 1, revolutions: int = 1, torque: float = 1.0, speed: float = 1.0,
                    cpr: int = COUNTS_PER_REV, table_length: int | None = None, feedforward: float = 0.0,
                    scale: float = 14.0, gain: float = 0.908) -> bytes:
    head = REQUEST_HEAD.pack(trial_id, revolutions, 7, cpr if table_length is None else table_length, torque, speed,
                             scale, scale, scale, 0.0, 0.0, 0.0, gain)
    return head + np.full(cpr, feedforward, "<f8").tobytes() + np.zeros(cpr, "<f8").tobytes()


@dataclass
class Request:
    """The fields of a received REQUEST a hostile target needs."""

    trial_id: int
    revolutions: int
    torque: float
    speed: float


def parse_request(payload: bytes) -> Request:
    trial_id, revolutions, _, _, torque, speed, *_ = REQUEST_HEAD.unpack_from(payload)
    return Request(trial_id, revolutions, torque, speed)


def honest_columns(req: Request) -> dict[str, np.ndarray]:
    """A plausible trial for ``req``: count, time, i_ref (n, 3), torque."""
    n = max(req.revolutions, 1) * COUNTS_PER_REV
    count = np.arange(n, dtype=np.int64) + 1000
    time_s = 1.0 + np.arange(n) / (COUNTS_PER_REV * req.speed)
    backemf = backemf_table()[count % COUNTS_PER_REV]
    tau = np.full(n, req.torque) + 0.02 * np.sin(48 * 2 * np.pi * count / COUNTS_PER_REV)
    i_ref = tau[:, None] * backemf / np.sum(backemf**2, axis=1)[:, None]
    return {"count": count, "time": time_s, "i_ref": i_ref, "torque": tau}


def data_payloads(trial_id: int, cols: dict[str, np.ndarray], chunk: int = 8192) -> list[bytes]:
    n = cols["count"].size
    out = []
    for start in range(0, n, chunk):
        s = slice(start, min(start + chunk, n))
        out.append(DATA_HEAD.pack(trial_id, 0, start, s.stop - s.start, 0)
                   + np.ascontiguousarray(cols["count"][s], "<i8").tobytes()
                   + b"".join(np.ascontiguousarray(cols[k][s], "<f8").tobytes() for k in ("time", "i_ref", "torque")))
    return out


def end_payload(trial_id: int, payloads: list[bytes], n: int) -> bytes:
    crc = 0
    for p in payloads:
        crc = zlib.crc32(p, crc)
    return END.pack(trial_id, len(payloads), n, crc, 0)


def error_payload(code: int, trial_id: int, message: bytes) -> bytes:
    return ERROR_HEAD.pack(code, trial_id) + message


# ---------------------------------------------------------------- hostile targets


def handshake(w: Wire, describe: bytes | None = None) -> Request | None:
    """HELLO -> DESCRIBE, then the REQUEST (None if the client went away)."""
    if w.recv() is None:
        return None
    w.send(FrameType.DESCRIBE, describe_payload() if describe is None else describe)
    frame = w.recv()
    return None if frame is None or frame[0] != FrameType.REQUEST else parse_request(frame[1])


def serve(describe: bytes | None = None, accept_samples: Callable[[int], int] = lambda n: n,
          mutate: Callable[[dict], None] | None = None, version: int = 1) -> Callable[[Wire, threading.Event], None]:
    """A target that answers every request with a whole trial, after ``mutate`` edits its columns."""

    def behaviour(w: Wire, stop: threading.Event) -> None:
        while (req := handshake(w, describe) if w.seq == 0 else _next_request(w)) is not None:
            cols = honest_columns(req)
            if mutate is not None:
                mutate(cols)
            n = cols["count"].size
            w.send(FrameType.ACCEPT, ACCEPT.pack(req.trial_id, 0, accept_samples(n)), version)
            payloads = data_payloads(req.trial_id, cols)
            for p in payloads:
                w.send(FrameType.DATA, p, version)
            w.send(FrameType.END_OF_TRIAL, end_payload(req.trial_id, payloads, n), version)
    return behaviour


def _next_request(w: Wire) -> Request | None:
    frame = w.recv()
    return None if frame is None or frame[0] != FrameType.REQUEST else parse_request(frame[1])


def _set(key: str, fn: Callable[[np.ndarray], None]) -> Callable[[dict], None]:
    return lambda cols: fn(cols[key])


def _count_jump(cols: dict) -> None:
    cols["count"][100:] += 10**15


def _reversed_time(cols: dict) -> None:
    cols["time"][:] = cols["time"][::-1]


def _one_sample(cols: dict) -> None:
    for k in cols:
        cols[k] = cols[k][:1]


def heartbeats_forever(w: Wire, stop: threading.Event) -> None:
    req = handshake(w)
    if req is None:
        return
    w.send(FrameType.ACCEPT, ACCEPT.pack(req.trial_id, 0, req.revolutions * COUNTS_PER_REV))
    while not stop.wait(0.3):
        w.send(FrameType.HEARTBEAT, HEARTBEAT.pack(req.trial_id, 0))


def slow_drip(w: Wire, stop: threading.Event) -> None:
    """A DATA frame one byte every 1.5 s: no single read ever times out."""
    req = handshake(w)
    if req is None:
        return
    w.send(FrameType.ACCEPT, ACCEPT.pack(req.trial_id, 0, req.revolutions * COUNTS_PER_REV))
    frame = w.frame(FrameType.DATA, data_payloads(req.trial_id, honest_columns(req))[0])
    for byte in frame:
        if stop.wait(1.5):
            return
        w.sock.sendall(bytes([byte]))


def silent(w: Wire, stop: threading.Event) -> None:
    stop.wait(60)


def busy_forever(w: Wire, stop: threading.Event) -> None:
    if w.recv() is not None:
        w.send(FrameType.ERROR, error_payload(ErrorCode.BUSY, 0, b"another client is connected"))


def raw_after_request(build: Callable[[Wire, Request], bytes]) -> Callable[[Wire, threading.Event], None]:
    """A target that answers the REQUEST with ``build``'s bytes, then waits for the client to close."""

    def behaviour(w: Wire, stop: threading.Event) -> None:
        req = handshake(w)
        if req is not None:
            w.sock.sendall(build(w, req))
            while w.recv() is not None and not stop.is_set():
                pass
    return behaviour


def _accept_then(extra: Callable[[Wire, Request], bytes]) -> Callable[[Wire, Request], bytes]:
    return lambda w, r: (w.frame(FrameType.ACCEPT, ACCEPT.pack(r.trial_id, 0, r.revolutions * COUNTS_PER_REV))
                         + extra(w, r))


def _bad_crc(w: Wire, r: Request) -> bytes:
    frame = bytearray(w.frame(FrameType.DATA, data_payloads(r.trial_id, honest_columns(r))[0]))
    frame[-1] ^= 0xFF
    return bytes(frame)


def _half_frame(w: Wire, r: Request) -> bytes:
    frame = w.frame(FrameType.DATA, data_payloads(r.trial_id, honest_columns(r))[0])
    return frame[:len(frame) // 2]


def _oversized_header(w: Wire, r: Request) -> bytes:
    return HEADER.pack(MAGIC, 1, FrameType.DATA, w.seq, 0xFFFFFFFF)


def _long_error(w: Wire, r: Request) -> bytes:
    return w.frame(FrameType.ERROR, error_payload(ErrorCode.TRIAL_FAILED, r.trial_id, b"x" * 100_000))


def _bad_trial_crc(w: Wire, r: Request) -> bytes:
    cols = honest_columns(r)
    payloads = data_payloads(r.trial_id, cols)
    end = bytearray(end_payload(r.trial_id, payloads, cols["count"].size))
    end[16] ^= 0xFF
    return b"".join(w.frame(FrameType.DATA, p) for p in payloads) + w.frame(FrameType.END_OF_TRIAL, bytes(end))


def _other_trial(w: Wire, r: Request) -> bytes:
    cols = honest_columns(r)
    payloads = data_payloads(r.trial_id + 7, cols)
    return (b"".join(w.frame(FrameType.DATA, p) for p in payloads)
            + w.frame(FrameType.END_OF_TRIAL, end_payload(r.trial_id + 7, payloads, cols["count"].size)))


def _unknown_type(w: Wire, r: Request) -> bytes:
    return w.frame(99, b"\0" * 8)


def _sequence_gap(w: Wire, r: Request) -> bytes:
    return w.frame(FrameType.ACCEPT, ACCEPT.pack(r.trial_id, 0, r.revolutions * COUNTS_PER_REV), seq=w.seq + 5)


@dataclass(frozen=True)
class TargetCase:
    """A misbehaving target; ``cli``: answer ``ilcpmac run --backend remote`` instead of the driver."""

    name: str
    behaviour: Callable[[Wire, threading.Event], None]
    must_reject: bool = True
    cli: bool = False


_NAN_LIMITS = describe_payload(limits=(float("nan"),) * 3)
TARGETS: tuple[TargetCase, ...] = (
    TargetCase("honest target (control)", serve(), must_reject=False),
    TargetCase("ACCEPT announces 2^62 samples", serve(accept_samples=lambda n: 2**62)),
    TargetCase("ACCEPT announces fewer samples than sent", serve(accept_samples=lambda n: n // 2)),
    TargetCase("heartbeats forever", heartbeats_forever),
    TargetCase("DATA dripped one byte per 1.5 s", slow_drip),
    TargetCase("NaN torque samples", serve(mutate=_set("torque", lambda a: a.__setitem__(slice(10, 20), np.nan)))),
    TargetCase("inf current references", serve(mutate=_set("i_ref", lambda a: a.__setitem__(5, np.inf)))),
    TargetCase("1e300 torque samples", serve(mutate=_set("torque", lambda a: a.__setitem__(slice(None), 1e300)))),
    TargetCase("NaN time stamps", serve(mutate=_set("time", lambda a: a.__setitem__(3, np.nan)))),
    TargetCase("count jumps by 10^15", serve(mutate=_count_jump)),
    TargetCase("reversed time", serve(mutate=_reversed_time)),
    TargetCase("a single sample", serve(mutate=_one_sample)),
    TargetCase("wrong frame CRC", raw_after_request(_accept_then(_bad_crc))),
    TargetCase("wrong trial CRC", raw_after_request(_accept_then(_bad_trial_crc))),
    TargetCase("DATA of another trial", raw_after_request(_accept_then(_other_trial))),
    TargetCase("half a frame, then silence", raw_after_request(_accept_then(_half_frame))),
    TargetCase("frame header announcing 4 GiB", raw_after_request(_accept_then(_oversized_header))),
    TargetCase("ERROR with a 100 kB message", raw_after_request(_long_error)),
    TargetCase("unknown frame type", raw_after_request(_accept_then(_unknown_type))),
    TargetCase("sequence gap", raw_after_request(_sequence_gap)),
    TargetCase("early close after HELLO", lambda w, stop: w.recv()),
    TargetCase("silent after connect", silent),
    TargetCase("BUSY to every HELLO", busy_forever),
    TargetCase("frames of protocol version 2", serve(version=2)),
    TargetCase("DESCRIBE with NaN limits", serve(describe=_NAN_LIMITS)),
    TargetCase("DESCRIBE with inertia -1", serve(describe=describe_payload(inertia=-1.0))),
    TargetCase("DESCRIBE with counts_per_rev 0", serve(describe=describe_payload(cpr=0, table_rows=0))),
    TargetCase("DESCRIBE with an inf back-EMF", serve(describe=describe_payload(
        backemf=np.where(np.arange(3 * COUNTS_PER_REV).reshape(-1, 3) == 7, np.inf, backemf_table())))),
    TargetCase("DESCRIBE with a zero back-EMF",
               serve(describe=describe_payload(backemf=np.zeros((COUNTS_PER_REV, 3))))),
    TargetCase("DESCRIBE with pole_pairs 10^6", serve(describe=describe_payload(pole_pairs=10**6))),
    TargetCase("run: DESCRIBE with NaN limits", serve(describe=_NAN_LIMITS), cli=True),
    TargetCase("run: NaN torque samples", serve(mutate=_set("torque", lambda a: a.__setitem__(slice(10, 20), np.nan))),
               cli=True),
    TargetCase("run: BUSY to every HELLO", busy_forever, cli=True),
    TargetCase("run: frames of protocol version 2", serve(version=2), cli=True),
)


class HostileTarget:
    """Serves ``behaviour`` to every connection on 127.0.0.1 (a thread per connection) until `stop`."""

    def __init__(self, behaviour: Callable[[Wire, threading.Event], None]) -> None:
        self.behaviour = behaviour
        self.stop_event = threading.Event()
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.1)
        self.address = f"127.0.0.1:{self.listener.getsockname()[1]}"
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        with self.listener:
            while not self.stop_event.is_set():
                try:
                    conn, _ = self.listener.accept()
                except TimeoutError:
                    continue
                threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn: socket.socket) -> None:
        conn.settimeout(60)
        with conn:
            try:
                self.behaviour(Wire(conn), self.stop_event)
            except OSError:
                pass  # the client closed on us: that is what a client should do

    def stop(self) -> None:
        self.stop_event.set()
        self.thread.join(5)


def client_main(address: str, out: str) -> int:
    """Run one trial on ``address`` with RemoteBackend and short timeouts; write what came back to ``out``.

    Exits like the CLI: 0 with the JSON written, or 2 with one ``error:`` line.
    """
    from ilcpmac.backends.remote import RemoteBackend
    from ilcpmac.core.errors import IlcpmacError
    from ilcpmac.core.records import SensorCalibration, TrialRequest

    try:
        with RemoteBackend(address, connect_timeout_s=2.0, read_timeout_s=2.0, retries=1, backoff_s=0.05,
                           trial_margin_s=2.0) as bench:
            cpr = bench.describe().motor.counts_per_rev
            trial = bench.run_trial(TrialRequest(
                1.0, 1.0, 2, np.zeros(cpr), np.zeros(cpr),
                SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908), seed=7))
    except IlcpmacError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    summary = {"n_samples": int(trial.count.size), "count": [int(trial.count[0]), int(trial.count[-1])]}
    for name in ("time_s", "i_ref_a", "torque_nm"):
        values = np.asarray(getattr(trial, name), float)
        summary[name] = [float(values.min()), float(values.max())]
    Path(out).write_text(json.dumps(summary))
    return 0


# ---------------------------------------------------------------- the emulator under attack


def limit_memory(cap_bytes: int) -> Callable[[], None]:
    """A preexec_fn capping the child's address space."""
    return lambda: resource.setrlimit(resource.RLIMIT_AS, (cap_bytes, cap_bytes))


class Emulator:
    """``ilcpmac emulate --port 0`` as a subprocess, with its stderr kept in a file."""

    def __init__(self, argv: list[str], folder: Path, cap_bytes: int, env: dict) -> None:
        self.log = folder / f"emulator-{time.monotonic_ns()}.log"
        self.out = self.log.with_suffix(".out")
        with open(self.out, "wb") as fo, open(self.log, "wb") as fe:
            self.proc = subprocess.Popen(argv, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL, env=env,
                                         preexec_fn=limit_memory(cap_bytes), start_new_session=True)
        self.seen = 0
        deadline = time.monotonic() + 60
        while not (m := re.search(r"listening on (\S+)", self.out.read_text())):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"emulator did not start: {self.log.read_text()[-500:]}")
            time.sleep(0.1)
        self.address = m.group(1)
        self.host, port = self.address.rsplit(":", 1)
        self.port = int(port)

    def new_output(self) -> str:
        """What the emulator wrote to stderr since the last call."""
        text = self.log.read_bytes()[self.seen:].decode("utf-8", "replace")
        self.seen += len(text.encode())
        return text

    def peak_rss_kib(self) -> int:
        try:
            return int(re.search(r"VmHWM:\s+(\d+)", Path(f"/proc/{self.proc.pid}/status").read_text()).group(1))
        except (OSError, AttributeError):
            return 0

    def stop(self) -> int:
        """SIGTERM, then SIGKILL after 10 s; the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return self.proc.returncode

    def connect(self, timeout: float = ANSWER_S) -> socket.socket:
        sock = socket.create_connection((self.host, self.port), timeout=timeout)
        sock.settimeout(timeout)
        return sock


def describes(em: Emulator, timeout: float = 5.0) -> bool:
    """Whether a well-formed client gets its DESCRIBE within ``timeout``."""
    try:
        with em.connect(timeout) as sock:
            w = Wire(sock)
            w.send(FrameType.HELLO)
            frame = w.recv()
            return frame is not None and frame[0] == FrameType.DESCRIBE
    except OSError:
        return False


def answer(sock: socket.socket, wait_s: float = ANSWER_S) -> str:
    """How the emulator reacts within ``wait_s``: 'closed', 'ERROR <code>', '<FRAME TYPE>' or 'open'."""
    sock.settimeout(wait_s)
    try:
        frame = Wire(sock).recv()
    except TimeoutError:
        return "open"
    except OSError:
        return "closed"
    if frame is None:
        return "closed"
    ftype, payload = frame
    if ftype == FrameType.ERROR and len(payload) >= 8:
        code = ERROR_HEAD.unpack_from(payload)[0]
        return f"ERROR {ErrorCode(code).name if code in ErrorCode._value2member_map_ else code}"
    return FrameType(ftype).name if ftype in FrameType._value2member_map_ else f"type {ftype}"


def after_hello(sock: socket.socket) -> Wire:
    w = Wire(sock)
    w.send(FrameType.HELLO)
    if answer(sock) != "DESCRIBE":
        raise OSError("no DESCRIBE")
    return w


@dataclass(frozen=True)
class Attack:
    """A hostile client. ``run(emulator)`` returns (accepted, what it saw): accepted means the
    emulator took the garbage as valid (answered it, or kept the connection open when it must close)."""

    name: str
    run: Callable[[Emulator], tuple[bool, str]]
    must_reject: bool = True


def _send_then(data: Callable[[Wire], bytes], hello: bool = False, ok: tuple[str, ...] = ("closed", "ERROR")):
    def run(em: Emulator) -> tuple[bool, str]:
        with em.connect() as sock:
            w = after_hello(sock) if hello else Wire(sock)
            try:
                sock.sendall(data(w))
            except (BrokenPipeError, ConnectionResetError):
                return False, "closed while the frame was being sent"
            seen = answer(sock)
            if seen.startswith("ERROR"):  # after an ERROR the emulator closes or stays open (by code)
                seen += "" if answer(sock, 1.0) == "closed" else " (left open)"
            return not seen.startswith(ok), seen
    return run


def _request(**fields) -> Callable[[Wire], bytes]:
    return lambda w: w.frame(FrameType.REQUEST, request_payload(**fields))


def _refused(**fields):
    """A REQUEST the emulator must refuse with an ERROR (not ACCEPT)."""
    def run(em: Emulator) -> tuple[bool, str]:
        with em.connect() as sock:
            w = after_hello(sock)
            w.send(FrameType.REQUEST, request_payload(**fields))
            seen = answer(sock)
            return seen == "ACCEPT", seen
    return run


def _valid_trial(em: Emulator) -> tuple[bool, str]:
    with em.connect(10.0) as sock:
        w = after_hello(sock)
        w.send(FrameType.REQUEST, request_payload())
        seen = []
        while (kind := answer(sock, 10.0)) not in ("END_OF_TRIAL", "closed", "open") and not kind.startswith("ERROR"):
            seen.append(kind)
        return kind == "END_OF_TRIAL", f"{len(seen)} frames then {kind}"


def _cancel_mid_trial(em: Emulator) -> tuple[bool, str]:
    with em.connect() as sock:
        w = after_hello(sock)
        w.send(FrameType.REQUEST, request_payload(revolutions=3))
        seen = answer(sock)
    return False, f"{seen}, then closed"


def _garbage_mid_trial(em: Emulator) -> tuple[bool, str]:
    with em.connect() as sock:
        w = after_hello(sock)
        w.send(FrameType.REQUEST, request_payload(revolutions=2))
        sock.sendall(os.urandom(4096))
        kinds = []
        while (kind := answer(sock)) not in ("closed", "open") and len(kinds) < 50:
            kinds.append(kind)
        return kind == "open", f"{kinds[:2]}... then {kind}"


def _second_controller(em: Emulator) -> tuple[bool, str]:
    """A holds a long trial (not reading its data); B asks for a trial meanwhile."""
    with em.connect() as a, em.connect() as b:
        wa = after_hello(a)
        wa.send(FrameType.REQUEST, request_payload(revolutions=40, speed=0.5))
        time.sleep(0.5)
        wb = Wire(b)
        wb.send(FrameType.HELLO)
        first = answer(b)
        if first != "DESCRIBE":
            return False, f"second client got {first}"
        wb.send(FrameType.REQUEST, request_payload())
        second = answer(b)
        return second == "ACCEPT", f"second client got DESCRIBE then {second} during the first one's trial"


def _many_connections(em: Emulator, n: int = 300) -> tuple[bool, str]:
    socks, refused = [], 0
    try:
        for _ in range(n):
            try:
                s = em.connect(1.0)
                Wire(s).send(FrameType.HELLO)
                socks.append(s)
            except OSError:
                refused += 1
        answers = [answer(s, 0.05 if i else ANSWER_S) for i, s in enumerate(socks)]
    finally:
        for s in socks:
            s.close()
    served = answers.count("DESCRIBE")
    return served > MAX_SESSIONS, (f"{served} of {n} simultaneous clients got DESCRIBE, "
                                   f"{answers.count('ERROR BUSY')} BUSY, {refused} not connected")


def _held_open(prepare: Callable[[socket.socket], None]):
    """The connection must be closed by the emulator within IDLE_CLOSE_S."""
    def run(em: Emulator) -> tuple[bool, str]:
        with em.connect() as sock:
            prepare(sock)
            start = time.monotonic()
            seen = answer(sock, IDLE_CLOSE_S)
            while seen not in ("closed", "open"):
                seen = answer(sock, max(0.1, IDLE_CLOSE_S - (time.monotonic() - start)))
            return seen == "open", f"{seen} after {time.monotonic() - start:.1f} s"
    return run


def _half_header(sock: socket.socket) -> None:
    sock.sendall(Wire(sock).frame(FrameType.HELLO)[:7])


def _half_request(sock: socket.socket) -> None:
    w = after_hello(sock)
    sock.sendall(w.frame(FrameType.REQUEST, request_payload())[:1000])


ATTACKS: tuple[Attack, ...] = (
    Attack("well-formed trial (control)", _valid_trial, must_reject=False),
    Attack("bad magic", _send_then(lambda w: b"XXXX" + w.frame(FrameType.HELLO)[4:])),
    Attack("length 0xFFFFFFFF", _send_then(lambda w: HEADER.pack(MAGIC, 1, FrameType.HELLO, 0, 0xFFFFFFFF))),
    Attack("length 16 MiB, zeros, bad CRC", _send_then(
        lambda w: HEADER.pack(MAGIC, 1, FrameType.REQUEST, 0, MAX_PAYLOAD) + bytes(MAX_PAYLOAD + 4))),
    Attack("bad CRC", _send_then(lambda w: w.frame(FrameType.HELLO)[:-1] + b"\0")),
    Attack("sequence gap", _send_then(lambda w: w.frame(FrameType.HELLO, seq=5))),
    Attack("unknown frame type", _send_then(lambda w: w.frame(77))),
    Attack("HELLO of version 2", _send_then(lambda w: w.frame(FrameType.HELLO, version=2))),
    Attack("REQUEST before HELLO", _send_then(_request())),
    Attack("HELLO twice", _send_then(lambda w: w.frame(FrameType.HELLO), hello=True)),
    Attack("DESCRIBE from the client", _send_then(lambda w: w.frame(FrameType.DESCRIBE, describe_payload()),
                                                  hello=True)),
    Attack("64 KiB of random bytes", _send_then(lambda w: os.urandom(65536))),
    Attack("ERROR from the client", _send_then(lambda w: w.frame(FrameType.ERROR, error_payload(8, 0, b"x")))),
    Attack("REQUEST payload shorter than its table", _send_then(
        lambda w: w.frame(FrameType.REQUEST, request_payload()[:-100]), hello=True)),
    Attack("REQUEST table_length 2^32-1", _send_then(
        lambda w: w.frame(FrameType.REQUEST, request_payload(table_length=2**32 - 1)), hello=True)),
    Attack("REQUEST table_length 0", _refused(cpr=0)),
    Attack("REQUEST NaN torque", _refused(torque=float("nan"))),
    Attack("REQUEST speed inf", _refused(speed=float("inf"))),
    Attack("REQUEST speed -1 Hz", _refused(speed=-1.0)),
    Attack("REQUEST speed 1e-4 Hz (unrunnable)", _refused(speed=1e-4)),
    Attack("REQUEST 0 revolutions", _refused(revolutions=0)),
    Attack("REQUEST 2^32-1 revolutions", _refused(revolutions=2**32 - 1)),
    Attack("REQUEST feed-forward 1e300", _refused(feedforward=1e300)),
    Attack("REQUEST current scale 0", _refused(scale=0.0)),
    Attack("REQUEST torque gain NaN", _refused(gain=float("nan"))),
    Attack("REQUEST above the speed limit", _refused(speed=1e6)),
    Attack("close right after REQUEST", _cancel_mid_trial, must_reject=False),
    Attack("random bytes mid-trial", _garbage_mid_trial),
    Attack("second controller during a trial", _second_controller),
    Attack("300 simultaneous connections", _many_connections),
)

#: attacks that wait out IDLE_CLOSE_S: run last, together
IDLE_ATTACKS: tuple[Attack, ...] = (
    Attack("idle connection (nothing sent)", _held_open(lambda sock: None)),
    Attack("half-sent header, then idle", _held_open(_half_header)),
    Attack("half-sent REQUEST, then idle", _held_open(_half_request)),
)


# ---------------------------------------------------------------- TCP ports that are no Dask scheduler


def http_reply(w: Wire, stop: threading.Event) -> None:
    """An HTTP server's answer to whatever comes (its first 8 bytes, read as a length, ask for 3 EiB)."""
    if w.sock.recv(65536):
        w.sock.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")


def echo(w: Wire, stop: threading.Event) -> None:
    """A TCP echo port: the client's own handshake and request come back instead of an answer."""
    while data := w.sock.recv(65536):
        w.sock.sendall(data)


def swallow(w: Wire, stop: threading.Event) -> None:
    """A port that takes everything and answers nothing."""
    while w.sock.recv(65536):
        pass


# ---------------------------------------------------------------- broken plugin stages

#: the broken stage's name, listed after the built-ins in the stage cases' [pipeline] stages
BROKEN_STAGE = "fuzz-broken"
_EVENT = threading.Event()  # never set: the hanging stages wait on it for ever


class Inert:
    """A stage that does nothing; each broken stage breaks one of its calls."""

    name = BROKEN_STAGE

    def __init__(self, setup) -> None:
        self.counts_per_rev = setup.description.motor.counts_per_rev
        self.calls = {"learn": 0, "state": 0}

    def columns(self, trial):
        return None

    def shape(self, request):
        return request

    def learn(self, trial, frame) -> None:
        self.calls["learn"] += 1

    def state(self) -> dict:
        self.calls["state"] += 1
        return {"learned": self.calls["learn"]}

    def restore(self, state: dict) -> None:
        pass


def _broken(method: str, fn: Callable) -> type:
    """An `Inert` whose ``method`` is ``fn(self, *args)`` (the factory: ``__init__``)."""
    return type(f"Broken_{method}", (Inert,), {method: fn})


def _raise(exc: BaseException) -> Callable:
    def call(self, *args):
        raise exc
    return call


def _after(method: str, n: int, fn: Callable) -> Callable:
    """``fn`` from the ``n``-th call of ``method`` on (Inert's own before): a failure after some trials ran."""
    def call(self, *args):
        value = getattr(Inert, method)(self, *args)
        return fn(self, *args) if self.calls[method] >= n else value
    return call


def _write_trial(self, trial, frame) -> None:
    trial.torque_nm[:] = np.nan


def _write_request(self, request):
    request.feedforward_nm[:] = 1e3
    return request


def _hang(self, *args):
    _EVENT.wait()


#: broken stages by case name: (factory, what the case says it does)
BROKEN_STAGES: dict[str, type] = {
    "factory raises": _broken("__init__", _raise(RuntimeError("no bench for me"))),
    "factory hangs": _broken("__init__", _hang),
    "shape raises": _broken("shape", _raise(ValueError("cannot shape this"))),
    "learn raises in the first learning round": _broken("learn", _after(
        "learn", 3, _raise(RuntimeError("diverged")))),
    "state raises at its 4th call": _broken("state", _after("state", 4, _raise(RuntimeError("lost my memory")))),
    "columns raises": _broken("columns", _raise(ZeroDivisionError("division by zero"))),
    "columns NaN": _broken("columns", lambda self, trial: np.full((self.counts_per_rev, 2), np.nan)),
    "columns inf": _broken("columns", lambda self, trial: np.full((self.counts_per_rev, 2), np.inf)),
    "columns (counts_per_rev, MAX_COLUMNS + 1)": _broken("columns", lambda self, trial: np.zeros(
        (self.counts_per_rev, 513))),
    "columns (10^7, 2) rows": _broken("columns", lambda self, trial: np.zeros((10**7, 2))),
    "columns a list of text": _broken("columns", lambda self, trial: [["a", "b"]] * self.counts_per_rev),
    "state not JSON (a set)": _broken("state", lambda self: {"seen": {1, 2}}),
    "state NaN": _broken("state", lambda self: {"gain": float("nan")}),
    "state an integer beyond 64 bits": _broken("state", lambda self: {"n": 2**70}),
    "state 64 MiB of text (2 x MAX_STATE_BYTES)": _broken("state", lambda self: {"memory": "x" * (64 << 20)}),
    "state a list, not an object": _broken("state", lambda self: [1, 2, 3]),
    "learn writes NaN into its trial": _broken("learn", _write_trial),
    "shape writes into its request": _broken("shape", _write_request),
    "shape raises SystemExit(0)": _broken("shape", _raise(SystemExit(0))),
    "learn raises SystemExit(0)": _broken("learn", _raise(SystemExit(0))),
    "learn hangs (blocks on an Event)": _broken("learn", _hang),
    "shape returns None": _broken("shape", lambda self, request: None),
}


# ---------------------------------------------------------------- lying values (issue 34, items 1 and 2)

def _claiming(base: type, claimed) -> type:
    """A subclass of ``base`` whose instances are ``claimed`` to every comparison and arithmetic operator, while the
    value they hold, as a kernel or a wire encoder reads it, is the one they were made with."""
    def claims(name: str) -> Callable:
        method = getattr(base, f"__{name}__")
        return lambda self, *args: method(base(claimed), *args)

    names = ("lt", "le", "gt", "ge", "eq", "ne", "add", "radd", "sub", "rsub", "mul", "rmul", "truediv", "rtruediv",
             "neg", "abs")
    return type(f"Claims{claimed}", (base,), {f"__{name}__": claims(name) for name in names})


class _ClaimingArray(np.ndarray):
    """An array that is ``claimed`` (its attribute) to every ufunc, np.abs, np.isfinite and reductions included,
    while its buffer holds what it was made with."""

    claimed: np.ndarray

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        plain = [x.claimed if isinstance(x, _ClaimingArray) else x for x in inputs]
        return getattr(ufunc, method)(*plain, **kwargs)


def _claiming_array(held: np.ndarray, claimed: np.ndarray) -> np.ndarray:
    array = np.array(held, float).view(_ClaimingArray)
    array.claimed = np.array(claimed, float)
    return array


def _lying(change: Callable) -> Callable:
    """A ``shape`` answering ``change(request)`` from the learning phase on (the trials after the compensation)."""
    def shape(self, request):
        self.calls["shape"] = self.calls.get("shape", 0) + 1
        return change(request) if self.calls["shape"] > 2 else request
    return shape


def _tripled_from_a_thread(self, request):
    """The request with a current-scale array the stage keeps, multiplied by 3 from a thread while the trial runs."""
    held = np.array(request.calibration.current_scale, float)
    threading.Timer(0.02, lambda: held.__imul__(3.0)).start()
    return request.with_changes(calibration=type(request.calibration)(
        held, request.calibration.current_offset, request.calibration.torque_gain))


#: stages whose answers lie to the checks by name: (factory, whether the run must be refused) (fuzz group "lying")
LYING_STAGES: dict[str, tuple[type, bool]] = {
    "speed a float subclass claiming 0.9 Hz, holding 2.27": (_broken("shape", _lying(
        lambda r: r.with_changes(speed_setpoint_hz=_claiming(float, 0.9)(2.27)))), True),
    "set point a float subclass claiming its own, holding 60 N m": (_broken("shape", _lying(
        lambda r: r.with_changes(torque_setpoint_nm=_claiming(float, r.torque_setpoint_nm)(60.0)))), True),
    "revolutions an int subclass claiming 6, holding 600": (_broken("shape", _lying(
        lambda r: r.with_changes(revolutions=_claiming(int, 6)(600)))), True),
    "feed-forward an ndarray subclass claiming zeros, holding 50 N m": (_broken("shape", _lying(
        lambda r: r.with_changes(feedforward_nm=_claiming_array(np.full(r.feedforward_nm.shape, 50.0),
                                                                 r.feedforward_nm)))), False),
    "current scales an ndarray subclass claiming its own, holding 3x": (_broken("shape", _lying(
        lambda r: r.with_changes(calibration=type(r.calibration)(_claiming_array(
            3.0 * r.calibration.current_scale, r.calibration.current_scale), r.calibration.current_offset,
            r.calibration.torque_gain)))), False),
    "current scales kept by the stage, tripled from a thread during the trial": (
        _broken("shape", _lying(lambda r: _tripled_from_a_thread(None, r))), False),
}


class _Entry:
    """An installed stage's entry point, as `ilcpmac.stages.registry` loads it."""

    def __init__(self, factory: type) -> None:
        self.factory = factory

    def load(self) -> type:
        return self.factory


# ---------------------------------------------------------------- the probe: ilcpmac run in a watched process

def _held(value):
    """What ``value`` holds, read past its class's operators, as the simulator's kernel or a wire encoder reads it."""
    if isinstance(value, np.ndarray):
        return np.ndarray.view(value, np.ndarray)
    if isinstance(value, float):
        return float.__float__(value)
    return int.__int__(value) if isinstance(value, int) else value


def limits_of(args: list[str]):
    """The [limits] of the config ``ilcpmac ARGS`` runs (``run CONFIG`` or ``run --resume DIR``), or None."""
    from ilcpmac.config import load_config

    if len(args) >= 3 and args[:2] == ["run", "--resume"]:
        path = Path(args[2]) / "campaign.toml"
    elif len(args) >= 2 and args[0] == "run" and args[1].endswith(".toml"):
        path = Path(args[1])
    else:
        return None
    try:
        return load_config(path).limits
    except Exception:  # the case's own config may be garbage: its run refuses it
        return None


def _extent_breach(request, bench_limits, limits, warmup_revolutions: int) -> str | None:
    """What of the speed, torque reference, samples or duration the simulator received (the values the request
    holds) is beyond the limits, or None."""
    speed, revolutions = _held(request.speed_setpoint_hz), _held(request.revolutions)
    torque = _held(request.torque_setpoint_nm) + _held(request.feedforward_nm) + _held(request.excitation_nm)
    if speed > bench_limits.max_speed_hz * (1 + 1e-9):
        return f"the simulator ran {speed:g} Hz, beyond max_speed_hz {bench_limits.max_speed_hz:g}"
    if np.abs(torque).max() > bench_limits.max_torque_nm * (1 + 1e-9):
        return (f"the simulator ran a torque reference of {np.abs(torque).max():g} N m, beyond "
                f"{bench_limits.max_torque_nm:g}")
    if limits is not None and (warmup_revolutions + revolutions) / speed > limits.max_trial_duration_s * (1 + 1e-9):
        return (f"the simulator ran {revolutions} revolutions at {speed:g} Hz, beyond max_trial_duration_s "
                f"{limits.max_trial_duration_s:g}")
    return None


#: the line the probe prints at its exit: trials sent to the simulator, the largest true phase current, the limit
PROBE = "fuzz-probe:"


def probe_main(argv: list[str]) -> None:
    """``ilcpmac ARGS`` run in this process as its executable runs it (`ilcpmac.cli.entry_point`), watched.

    argv: ``[--stage NAME] [--stage-call-s S] [--interrupt-at N] -- ARGS``. ``--stage``: the broken stage
    `BROKEN_STAGES` [NAME] installed as `BROKEN_STAGE`; ``--stage-call-s``: `STAGE_CALL_S` lowered to S;
    ``--interrupt-at``: Ctrl-C at the N-th trial (a run stopped part way). Every trial on the simulator is
    counted and its true phase currents kept; at exit a `PROBE` line on stdout gives the trials sent, the largest
    |i_true| and the simulator's max_current_a ([limits], the smaller of it and the bench's).
    """
    import atexit

    import ilcpmac.backends.simulated as simulated
    import ilcpmac.pipeline.pipeline as pipeline
    import ilcpmac.stages.registry as registry

    split = argv.index("--")
    opts, args = dict(zip(argv[:split:2], argv[1:split:2])), argv[split + 1:]
    seen = {"requests": 0, "peak_a": 0.0, "limit_a": float("nan")}
    lock = threading.Lock()
    run_trial = simulated.SimulatorBackend.run_trial
    interrupt_at = int(opts.get("--interrupt-at", 0))

    def watched(self, request):
        with lock:
            seen["requests"] += 1
            n = seen["requests"]
        if n == interrupt_at:
            raise KeyboardInterrupt
        breach = _extent_breach(request, self.limits, limits_of(args), self.simulator.warmup_revolutions)
        if breach is not None:
            with lock:
                seen.setdefault("breach", breach)
        trial = run_trial(self, request)
        peak = float(np.abs(trial.i_true_a).max()) if trial.i_true_a is not None else float("inf")
        with lock:
            seen["peak_a"] = max(seen["peak_a"], peak)
            seen["limit_a"] = self.limits.max_current_a
        return trial

    simulated.SimulatorBackend.run_trial = watched
    if "--stage" in opts:
        installed = registry.installed_stages
        factory = BROKEN_STAGES[opts["--stage"]] if opts["--stage"] in BROKEN_STAGES else \
            LYING_STAGES[opts["--stage"]][0]
        registry.installed_stages = lambda: {**installed(), BROKEN_STAGE: _Entry(factory)}
    if "--stage-call-s" in opts:
        pipeline.STAGE_CALL_S = float(opts["--stage-call-s"])
    atexit.register(lambda: print(f"{PROBE} requests {seen['requests']} peak_true_current_a {seen['peak_a']!r} "
                                  f"max_current_a {seen['limit_a']!r}"
                                  + (f"\n{PROBE}-breach {seen['breach']}" if "breach" in seen else ""), flush=True))
    from ilcpmac.cli import entry_point

    sys.argv = ["ilcpmac", *args]
    entry_point()


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "probe":
        probe_main(sys.argv[2:])
    if len(sys.argv) != 4 or sys.argv[1] != "client":
        sys.exit("usage: python benchmarks/fuzz_targets.py client HOST:PORT OUT.json | probe [OPTIONS] -- ARGS")
    sys.exit(client_main(sys.argv[2], sys.argv[3]))
