"""The bench protocol's frames and messages (docs/protocol.md), over socket pairs."""

from __future__ import annotations

import dataclasses
import re
import socket
import struct
import threading
import time
import tracemalloc
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from protocol_helpers import documented_frames

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.backends.protocol import (
    COLUMNS,
    HEADER,
    MAX_PAYLOAD,
    PAYLOAD_BOUNDS,
    PROTOCOL_VERSION,
    Accept,
    Channel,
    Column,
    EndOfTrial,
    ErrorCode,
    FrameTimeout,
    FrameType,
    PeerClosed,
    ProtocolError,
    ProtocolVersionError,
    SampleBounds,
    TargetError,
    TrialAssembler,
    check_request,
    data_bound,
    decode_accept,
    decode_describe,
    decode_end,
    decode_error,
    decode_heartbeat,
    decode_request,
    encode_accept,
    encode_describe,
    encode_end,
    encode_error,
    encode_heartbeat,
    encode_request,
    encode_trial,
    target_bounds,
)
from ilcpmac.core.errors import BackendError
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData, TrialRequest

CAL = SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908)
#: sample bounds no toy trial reaches
LOOSE = SampleBounds(10**6, dict.fromkeys(["i_ref_a", "i_meas_a", "i_true_a", "torque_nm", "torque_true_nm",
                                           "speed_true_rad_s"], 100.0))


@pytest.fixture
def pair(request):
    """(sender, receiver) channels over a connected socket pair, closed afterwards."""
    a, b = socket.socketpair()
    for s in (a, b):
        s.settimeout(2.0)
    sender, receiver = Channel(a, "the receiver"), Channel(b, "the sender")
    request.addfinalizer(sender.close)
    request.addfinalizer(receiver.close)
    return sender, receiver


def toy_description(cpr: int = 4) -> BenchDescription:
    theta = 2 * np.pi * np.arange(cpr) / cpr
    backemf = 0.2 * np.sin(8 * theta[:, None] - 2 * np.pi * np.arange(3) / 3)
    if cpr == 4:
        backemf = np.array([[0.2, -0.1, -0.1], [0.1, 0.2, -0.1], [-0.1, 0.1, 0.2], [0.0, -0.2, 0.2]])
    return BenchDescription(MotorInfo(8, 48, cpr, 0.01056), backemf, CAL, BenchLimits(30.0, 8.0, 1.5))


def toy_trial(n: int, flags: Column, seed: int = 0) -> TrialData:
    rng = np.random.default_rng(seed)
    optional = {name: (rng.standard_normal((n, 3)) if width == 3 else rng.standard_normal(n))
                for name, width, _, flag in COLUMNS if flag is not None and flags & flag}
    return TrialData(1.5, 0.7, count=np.cumsum(rng.integers(1, 3, n)), time_s=np.cumsum(0.1 + rng.random(n)),
                     i_ref_a=rng.standard_normal((n, 3)), torque_nm=rng.standard_normal(n), **optional)


def stream(trial: TrialData, chunk: int, trial_id: int = 7) -> tuple[list[memoryview], memoryview]:
    """The DATA payloads and END_OF_TRIAL payload of ``trial`` as bytes."""
    frames = [memoryview(b"".join(bytes(memoryview(p).cast("B")) for p in parts))
              for _, parts in encode_trial(trial_id, trial, chunk)]
    return frames[:-1], frames[-1]


# ---------------------------------------------------------------- frames


@pytest.mark.parametrize("ftype", list(FrameType))
def test_frame_round_trip(pair, ftype):
    sender, receiver = pair
    payload = (bytes(range(100)) + np.arange(4.0).astype("<f8").tobytes() + bytes(range(256)) * 3)
    payload = payload[:PAYLOAD_BOUNDS[ftype]]
    sender.send(ftype, [payload[:3], np.frombuffer(payload[3:], np.uint8)])
    sender.send(ftype)
    first, second = receiver.recv(), receiver.recv()
    assert (first.type, first.seq, first.version) == (ftype, 0, PROTOCOL_VERSION)
    assert bytes(first.payload) == payload
    assert (second.seq, bytes(second.payload)) == (1, b"")


def test_large_frames_round_trip(pair):
    sender, receiver = pair
    payload = np.random.default_rng(5).integers(0, 256, 3 * 1024 * 1024 + 5, dtype=np.uint8)
    thread = threading.Thread(target=sender.send, args=(FrameType.DATA, [payload]))
    thread.start()
    frame = receiver.recv()
    thread.join()
    assert np.array_equal(np.frombuffer(frame.payload, np.uint8), payload)


def test_frame_layout_is_header_payload_crc(pair):
    sender, _ = pair
    frame = sender.frame_bytes(FrameType.DATA, [b"abc"])
    assert frame[:4] == b"ILCP" and len(frame) == 16 + 3 + 4
    assert struct.unpack("<HHII", frame[4:16]) == (PROTOCOL_VERSION, 5, 0, 3)
    assert struct.unpack("<I", frame[-4:])[0] == zlib.crc32(frame[:-4])


@pytest.mark.parametrize("where", [5, 10, 16, 40, -1])
def test_corrupted_byte_is_rejected(pair, where):
    sender, receiver = pair
    frame = sender.frame_bytes(FrameType.DATA, [np.arange(8.0)])
    frame[where] ^= 0x10
    sender.send_bytes(frame)
    with pytest.raises(ProtocolError, match=r"CRC mismatch in frame \d+ \((DATA|type \d+)\) from the sender"):
        receiver.recv()


def test_bad_magic_is_rejected(pair):
    sender, receiver = pair
    frame = sender.frame_bytes(FrameType.HELLO)
    frame[0:4] = b"HTTP"
    sender.send_bytes(frame)
    with pytest.raises(ProtocolError, match="bad magic b'HTTP'"):
        receiver.recv()


def test_oversized_length_is_rejected_before_reading(pair):
    sender, receiver = pair
    sender.send_bytes(HEADER.pack(b"ILCP", PROTOCOL_VERSION, FrameType.DATA, 0, MAX_PAYLOAD + 1))
    with pytest.raises(ProtocolError, match="announces 16777217 payload bytes"):
        receiver.recv()


@pytest.mark.parametrize("bounds", [PAYLOAD_BOUNDS, target_bounds(4096)], ids=["any", "target"])
@pytest.mark.parametrize("ftype", list(FrameType))
def test_a_length_beyond_its_frame_types_bound_is_rejected_before_reading(pair, bounds, ftype):
    sender, receiver = pair
    receiver.bounds = dict(bounds)
    sender.send_bytes(HEADER.pack(b"ILCP", PROTOCOL_VERSION, ftype, 0, bounds[ftype] + 1))
    with pytest.raises(ProtocolError, match=rf"^{ftype.name} frame from the sender announces {bounds[ftype] + 1} "
                                            rf"payload bytes \(at most {bounds[ftype]}\)$"):
        receiver.recv()


def test_the_target_bounds_follow_the_protocol():
    bounds = target_bounds(4096)
    assert bounds[FrameType.REQUEST] == 88 + 16 * 4096 and bounds[FrameType.ERROR] == 8 + 1024
    assert {t for t, b in bounds.items() if b == 0} == set(FrameType) - {FrameType.REQUEST, FrameType.ERROR}
    assert (data_bound(2), data_bound(10**9)) == (24 + 2 * 112, MAX_PAYLOAD)


def test_a_half_sent_frame_costs_only_what_arrived(pair):
    sender, receiver = pair
    sender.send_bytes(HEADER.pack(b"ILCP", PROTOCOL_VERSION, FrameType.DATA, 0, MAX_PAYLOAD) + bytes(1000))
    sender.sock.shutdown(socket.SHUT_WR)
    tracemalloc.start()
    try:
        with pytest.raises(ProtocolError, match="closed the connection mid-frame"):
            receiver.recv()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 * 1024 * 1024


def test_a_dribbled_frame_times_out(pair):
    sender, receiver = pair
    receiver.frame_timeout_s = 0.05
    sender.send_bytes(sender.frame_bytes(FrameType.HELLO)[:10])
    with pytest.raises(FrameTimeout, match="the sender sent no complete frame in time"):
        receiver.recv()


def test_a_deadline_cuts_the_wait_for_a_frame(pair):
    sender, receiver = pair
    with pytest.raises(FrameTimeout, match="the sender sent no complete frame in time"):
        receiver.recv(deadline=time.monotonic() + 0.05)
    assert receiver.sock.gettimeout() == 2.0  # the socket's own timeout again
    sender.send(FrameType.HELLO)
    assert receiver.recv(deadline=time.monotonic() + 30.0).type is FrameType.HELLO


def test_peer_closed_sees_a_closed_connection_without_reading(pair):
    sender, receiver = pair
    sender.send(FrameType.HELLO)
    assert not receiver.peer_closed() and not sender.peer_closed()
    sender.close()
    assert not receiver.peer_closed()  # a frame is still waiting
    assert receiver.recv().type is FrameType.HELLO
    assert receiver.peer_closed()


def test_oversized_payload_is_not_sent(pair):
    sender, _ = pair
    with pytest.raises(ProtocolError, match="exceeds the 16777216-byte maximum"):
        sender.frame_bytes(FrameType.DATA, [bytes(MAX_PAYLOAD + 1)])


@pytest.mark.parametrize("keep", [3, 16, 30])
def test_truncated_frame_is_rejected(pair, keep):
    sender, receiver = pair
    sender.send_bytes(sender.frame_bytes(FrameType.DATA, [bytes(20)])[:keep])
    sender.sock.shutdown(socket.SHUT_WR)
    with pytest.raises(ProtocolError, match="closed the connection mid-frame"):
        receiver.recv()


def test_close_between_frames_is_peer_closed(pair):
    sender, receiver = pair
    sender.send(FrameType.HELLO)
    sender.sock.shutdown(socket.SHUT_WR)
    assert receiver.recv().type is FrameType.HELLO
    with pytest.raises(PeerClosed, match="the sender closed the connection"):
        receiver.recv()


def test_wrong_version_is_rejected(pair):
    sender, receiver = pair
    sender.send_bytes(sender.frame_bytes(FrameType.DESCRIBE, [b""], version=PROTOCOL_VERSION + 1))
    with pytest.raises(ProtocolVersionError, match="speaks protocol version 2, this end speaks version 1"):
        receiver.recv()


def test_error_frame_of_another_version_is_still_read(pair):
    sender, receiver = pair
    sender.send_bytes(sender.frame_bytes(FrameType.ERROR, encode_error(ErrorCode.VERSION_MISMATCH, 0, "v3 only"),
                                         version=3))
    frame = receiver.recv()
    assert (frame.type, frame.version) == (FrameType.ERROR, 3)
    error = decode_error(frame.payload)
    assert (error.code, error.detail) == (ErrorCode.VERSION_MISMATCH, "v3 only")


def test_sequence_gap_is_rejected(pair):
    sender, receiver = pair
    sender.frame_bytes(FrameType.DATA, [b"lost"])
    sender.send(FrameType.DATA, [b"next"])
    with pytest.raises(ProtocolError, match="sequence gap .*expected frame 0, got 1"):
        receiver.recv()


def test_unknown_frame_type_is_rejected(pair):
    sender, receiver = pair
    frame = bytearray(HEADER.pack(b"ILCP", PROTOCOL_VERSION, 99, 0, 0))
    sender.send_bytes(frame + struct.pack("<I", zlib.crc32(frame)))
    with pytest.raises(ProtocolError, match="unknown frame type 99"):
        receiver.recv()


# ---------------------------------------------------------------- messages


def test_describe_round_trip():
    description = toy_description(64)
    parts = encode_describe(description)
    back = decode_describe(memoryview(b"".join(bytes(memoryview(p).cast("B")) for p in parts)))
    assert back.motor == description.motor and back.limits == description.limits
    assert np.array_equal(back.backemf_nm_per_a, description.backemf_nm_per_a)
    assert np.array_equal(back.calibration.current_scale, CAL.current_scale)
    assert back.calibration.torque_gain == CAL.torque_gain


@pytest.mark.parametrize("change, message", [
    (lambda d: dataclasses.replace(d, motor=MotorInfo(8, 48, 64, -1.0)), r"inertia must lie in \[1e-08, .*got -1.0$"),
    (lambda d: dataclasses.replace(d, motor=MotorInfo(10**6, 48, 64, 0.01)), r"pole_pairs must lie in \[1, "),
    (lambda d: dataclasses.replace(d, motor=MotorInfo(8, 48, 0, 0.01), backemf_nm_per_a=np.zeros((0, 3))),
     r"counts_per_rev must lie in \[4, "),
    (lambda d: dataclasses.replace(d, limits=BenchLimits(np.nan, 8.0, 1.5)), r"max_current_a must be positive"),
    (lambda d: dataclasses.replace(d, calibration=SensorCalibration([14, 0, 14], [0, 0, 0], 0.9)),
     r"current_scale must be positive and finite"),
    (lambda d: dataclasses.replace(d, backemf_nm_per_a=np.where(np.arange(192).reshape(64, 3) == 7, np.inf,
                                                                  d.backemf_nm_per_a)),
     r"current_offset and back-EMF table must be finite"),
])
def test_a_describe_no_bench_can_send_is_refused(change, message):
    head, backemf = encode_describe(change(toy_description(64)))
    with pytest.raises(BackendError, match="^DESCRIBE " + message):
        decode_describe(memoryview(head + backemf.tobytes()))


def test_request_round_trip_keeps_every_field_and_the_seed():
    rng = np.random.default_rng(3)
    request = TrialRequest(2.5, 0.75, 3, rng.standard_normal(32), rng.standard_normal(32),
                           SensorCalibration([13.0, 14.0, 15.0], [0.5, -1.0, 2.0], 0.9), seed=2**32 - 1)
    payload = memoryview(b"".join(bytes(memoryview(p).cast("B")) for p in encode_request(42, request)))
    trial_id, back = decode_request(payload)
    assert trial_id == 42 and back.seed == 2**32 - 1
    assert (back.torque_setpoint_nm, back.speed_setpoint_hz, back.revolutions) == (2.5, 0.75, 3)
    assert np.array_equal(back.feedforward_nm, request.feedforward_nm)
    assert np.array_equal(back.excitation_nm, request.excitation_nm)
    assert np.array_equal(back.calibration.current_offset, [0.5, -1.0, 2.0])
    with pytest.raises(ProtocolError, match=r"REQUEST \(table length 32\) payload is 343 bytes, expected 600"):
        decode_request(payload[:-257])


def test_small_messages_round_trip():
    assert decode_accept(memoryview(b"".join(encode_accept(Accept(3, 2**40))))) == Accept(3, 2**40)
    assert decode_heartbeat(memoryview(b"".join(encode_heartbeat(9)))) == 9
    end = EndOfTrial(5, 2, 1000, 0xDEADBEEF)
    assert decode_end(memoryview(b"".join(encode_end(end)))) == end
    error = decode_error(memoryview(b"".join(encode_error(ErrorCode.TRIAL_FAILED, 4, "stalled at 3 \u00b0"))))
    assert isinstance(error, TargetError) and error.trial_id == 4
    assert str(error) == "target error TRIAL_FAILED: stalled at 3 \u00b0"
    assert str(decode_error(memoryview(struct.pack("<II", 77, 0)))) == "target error code 77: "
    assert len(b"".join(encode_error(ErrorCode.INTERNAL, 0, "x" * 5000))) == 8 + 1024
    with pytest.raises(ProtocolError, match="ACCEPT payload is 15 bytes, expected 16"):
        decode_accept(memoryview(bytes(15)))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 300), chunk=st.integers(1, 70), flags=st.integers(0, 15))
def test_trial_round_trip(n, chunk, flags):
    trial = toy_trial(n, Column(flags), seed=n)
    data, end = stream(trial, chunk)
    assembler = TrialAssembler(7, n, LOOSE)
    for payload in data:
        assembler.add(payload)
    columns = assembler.finish(end)
    assert len(data) == -(-n // chunk)
    for name, _, dtype, flag in COLUMNS:
        if flag is None or flags & flag:
            assert columns[name].dtype == dtype and np.array_equal(columns[name], getattr(trial, name))
        else:
            assert name not in columns


def _assemble(data, end, trial_id: int = 7, max_samples: int = 100, bounds: SampleBounds = LOOSE):
    assembler = TrialAssembler(trial_id, max_samples, bounds)
    for payload in data:
        assembler.add(payload)
    return assembler.finish(end)


def test_trial_with_a_missing_chunk_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    with pytest.raises(ProtocolError, match="starts at sample 20, expected 10"):
        _assemble([data[0], *data[2:]], end)


def test_trial_with_a_duplicated_chunk_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    with pytest.raises(ProtocolError, match="starts at sample 10, expected 20"):
        _assemble([data[0], data[1], data[1], *data[2:]], end)


def test_trial_cut_before_its_last_chunk_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    with pytest.raises(ProtocolError, match="announces 40 samples in 4 frames, received 30 in 3"):
        _assemble(data[:-1], end)


def test_trial_of_another_id_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    with pytest.raises(ProtocolError, match="DATA frame of trial 7 during trial 8"):
        _assemble(data, end, trial_id=8)


def test_trial_checksum_mismatch_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    bad_end = memoryview(b"".join(encode_end(EndOfTrial(7, 4, 40, 12345))))
    with pytest.raises(ProtocolError, match="trial checksum mismatch"):
        _assemble(data, bad_end)


def test_trial_beyond_announced_samples_is_rejected():
    data, end = stream(toy_trial(40, Column(0)), 10)
    with pytest.raises(ProtocolError, match=r"10 samples at 30 \(at most 35 announced\)"):
        _assemble(data, end, max_samples=35)


def test_trial_whose_flags_change_is_rejected():
    first, _ = stream(toy_trial(20, Column(0)), 10)
    second, end = stream(toy_trial(20, Column.I_MEAS), 10)
    with pytest.raises(ProtocolError, match="column flags changed from 0x0 to 0x1"):
        _assemble([first[0], second[1]], end)


def test_trial_with_unknown_flags_is_rejected():
    data, end = stream(toy_trial(20, Column(0)), 20)
    payload = bytearray(data[0])
    payload[4] = 0x10
    with pytest.raises(ProtocolError, match="unknown column flags 0x10"):
        _assemble([memoryview(payload)], end)


def test_trial_whose_counts_do_not_increase_is_rejected():
    trial = toy_trial(20, Column(0))
    data, end = stream(TrialData(1.0, 1.0, trial.count[::-1].copy(), trial.time_s, trial.i_ref_a,
                                 trial.torque_nm), 20)
    with pytest.raises(ProtocolError, match=r"DATA sample 1: count \d+ after \d+ \(must be finite and increase"):
        _assemble(data, end)


# ---------------------------------------------------------------- requests a target accepts


def _request(cpr: int = 64, **changes) -> TrialRequest:
    request = TrialRequest(2.0, 1.0, 1, np.zeros(cpr), 0.1 * np.sin(np.arange(cpr)), CAL, seed=1)
    return request.with_changes(**changes)


@pytest.mark.parametrize("changes, code, message", [
    ({}, None, None),
    ({"excitation_nm": np.zeros(63)}, ErrorCode.BAD_REQUEST, r"excitation_nm has shape \(63,\)"),
    ({"feedforward_nm": np.full(64, np.nan)}, ErrorCode.BAD_REQUEST, "NaN"),
    ({"seed": 2**32}, ErrorCode.BAD_REQUEST, "seed must be a 32-bit"),
    ({"revolutions": 0}, ErrorCode.BAD_REQUEST, "revolutions must be"),
    ({"speed_setpoint_hz": 0.0}, ErrorCode.BAD_REQUEST, "speed set point must be positive"),
    ({"calibration": SensorCalibration([14, 0, 14], [0, 0, 0], 1)}, ErrorCode.BAD_REQUEST, "calibration"),
    ({"speed_setpoint_hz": 1.6}, ErrorCode.LIMIT_EXCEEDED, "speed set point 1.6 Hz exceeds the bench limit"),
    ({"torque_setpoint_nm": 7.95}, ErrorCode.LIMIT_EXCEEDED, r"torque reference 8.05 N m at count 33 .* of 8 N m"),
    ({"torque_setpoint_nm": -7.95}, ErrorCode.LIMIT_EXCEEDED, r"torque reference -8.05 N m at count 11"),
])
def test_check_request(changes, code, message):
    result = check_request(_request(**changes), toy_description(64))
    if code is None:
        assert result is None
    else:
        assert result[0] is code and re.search(message, result[1])


def test_check_request_bounds_the_current_references():
    # K = 0.2 sin(...): i*_p = tau K_p / sum K^2 peaks at tau / (1.5 * 0.2) per phase
    description = toy_description(64)
    tight = BenchDescription(description.motor, description.backemf_nm_per_a, CAL, BenchLimits(6.0, 8.0, 1.5))
    assert check_request(_request(torque_setpoint_nm=1.7), tight) is None
    code, message = check_request(_request(torque_setpoint_nm=2.0), tight)
    assert code is ErrorCode.LIMIT_EXCEEDED
    assert re.fullmatch(r"current reference 6.\d+ A in phase [abc] at count \d+ exceeds the bench limit of 6 A",
                        message)


# ---------------------------------------------------------------- the worked example of docs/protocol.md


def test_worked_example_in_the_docs_matches_the_implementation():
    dumps = documented_frames()
    assert [d.name for d in dumps] == ["HELLO", "DESCRIBE", "REQUEST", "ACCEPT", "DATA", "DATA", "END_OF_TRIAL",
                                     "ERROR"]
    a, b = socket.socketpair()
    try:
        client, target = Channel(a, "client"), Channel(b, "target")
        request = TrialRequest(2.0, 0.5, 1, np.zeros(4), np.array([0.1, 0.0, -0.1, 0.0]), CAL, seed=2009)
        trial = TrialData(2.0, 0.5, np.arange(4), np.array([0.0, 0.5, 1.0, 1.5]),
                          np.arange(12.0).reshape(4, 3) / 10, np.array([2.0, 2.1, 1.9, 2.0]))
        frames = [client.frame_bytes(FrameType.HELLO),
                  target.frame_bytes(FrameType.DESCRIBE, encode_describe(toy_description(4))),
                  client.frame_bytes(FrameType.REQUEST, encode_request(1, request)),
                  target.frame_bytes(FrameType.ACCEPT, encode_accept(Accept(1, 4))),
                  *(target.frame_bytes(ftype, parts) for ftype, parts in encode_trial(1, trial, 2)),
                  target.frame_bytes(FrameType.ERROR, encode_error(ErrorCode.LIMIT_EXCEEDED, 2, "speed"))]
    finally:
        a.close()
        b.close()
    for dump, frame in zip(dumps, frames):
        assert dump.size == len(dump.data) and struct.unpack_from("<I", dump.data, 8)[0] == dump.seq
        assert dump.data == bytes(frame), dump.name


def test_a_bench_finer_than_a_describe_frame_carries_is_refused_before_serving():
    from ilcpmac.backends.emulator import BenchEmulator
    from ilcpmac.backends.protocol import MAX_COUNTS_PER_REV, MAX_PAYLOAD, check_servable

    fits = toy_description(4)
    fits = dataclasses.replace(fits, motor=MotorInfo(8, 48, MAX_COUNTS_PER_REV, 0.01),
                               backemf_nm_per_a=np.zeros((MAX_COUNTS_PER_REV, 3)))
    assert sum(memoryview(p).cast("B").nbytes for p in encode_describe(fits)) <= MAX_PAYLOAD
    too_fine = dataclasses.replace(fits, motor=MotorInfo(8, 48, MAX_COUNTS_PER_REV + 1, 0.01),
                                   backemf_nm_per_a=np.zeros((MAX_COUNTS_PER_REV + 1, 3)))
    with pytest.raises(BackendError, match=f"^counts_per_rev {MAX_COUNTS_PER_REV + 1} is more than the protocol's"):
        check_servable(too_fine)

    class Fine:
        def describe(self):
            return too_fine

    with pytest.raises(BackendError, match="serve the encoder at a divided resolution$"):
        BenchEmulator(Fine())


def test_a_bench_without_a_torque_sensor_says_so_in_describe():
    from ilcpmac.backends.protocol import NO_TORQUE_SENSOR

    description = toy_description(64)
    without = dataclasses.replace(description, motor=dataclasses.replace(description.motor, torque_sensor=False))
    head, backemf = encode_describe(without)
    assert int.from_bytes(head[12:16], "little") == NO_TORQUE_SENSOR
    assert decode_describe(memoryview(head + backemf.tobytes())).motor.torque_sensor is False
    head, backemf = encode_describe(description)
    assert decode_describe(memoryview(head + backemf.tobytes())).motor.torque_sensor is True
    with pytest.raises(BackendError, match=r"^DESCRIBE flags 0x3: unknown bits"):
        decode_describe(memoryview(head[:12] + (3).to_bytes(4, "little") + head[16:] + backemf.tobytes()))
