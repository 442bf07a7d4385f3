"""The portable C99 frame codec of firmware/ against docs/protocol.md and `ilcpmac.backends.protocol` (issue 13).

One driver, compiled once per module with the system C compiler (with AddressSanitizer and
UndefinedBehaviorSanitizer where the compiler has them), reads one command a line and prints one line
each: every number in hex (doubles as their 64 bits), every byte string as hex, ``-`` when empty. Every
decode gets its input in a heap block of exactly its size, so any read beyond it is caught.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shutil
import socket
import struct
import subprocess
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from protocol_helpers import DocumentedFrame, documented_frames

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.backends.protocol import (
    COLUMNS,
    HEADER,
    MAX_PAYLOAD,
    PAYLOAD_BOUNDS,
    PROTOCOL_VERSION,
    Accept,
    Channel,
    EndOfTrial,
    ErrorCode,
    FrameType,
    ProtocolError,
    ProtocolVersionError,
    SampleBounds,
    TargetError,
    TrialAssembler,
    check_request,
    check_trial_id,
    data_bound,
    decode_accept,
    decode_describe,
    decode_end,
    decode_error,
    decode_heartbeat,
    decode_request,
    encode_describe,
    encode_request,
    encode_trial,
    target_bounds,
)
from ilcpmac.core.errors import BackendError
from ilcpmac.core.records import MOTOR_RANGES, MotorInfo, SensorCalibration, TrialData, TrialRequest
from ilcpmac.pipeline.safety import MalformedRequest, owned_request

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"
#: the warnings issue 13 asks the codec to compile without
STRICT = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]
CAL = SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908)
CPR = 64
_THETA = 2 * np.pi * np.arange(CPR) / CPR
DESCRIPTION = BenchDescription(MotorInfo(8, 48, CPR, 0.01056),
                               0.2 * np.sin(8 * _THETA[:, None] - 2 * np.pi * np.arange(3) / 3), CAL,
                               BenchLimits(30.0, 8.0, 1.5))
REQUEST = TrialRequest(2.0, 1.0, 1, np.zeros(CPR), 0.1 * np.sin(np.arange(CPR)), CAL, seed=1)

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "ilcpmac_protocol.h"

static const char *const STATUS[] = {%(statuses)s};

static void *block(size_t n) { void *p = malloc(n ? n : 1u); if (!p) { exit(3); } return p; }
static char *next(void)
{
    char *t = strtok(NULL, " ");
    if (!t) { fputs("missing argument\n", stderr); exit(2); }
    return t;
}
static uint64_t u(void) { return strtoull(next(), NULL, 16); }
static uint32_t u32(void) { return (uint32_t)u(); }
static double f(void) { uint64_t b = u(); double v; memcpy(&v, &b, 8u); return v; }
static double *fs(size_t n)
{
    double *v = block(n * sizeof *v);
    size_t i;
    for (i = 0u; i < n; i++) v[i] = f();
    return v;
}

/* the next argument's bytes in a block of exactly their size */
static uint8_t *bytes(size_t *n)
{
    char *t = next();
    size_t i, len = strcmp(t, "-") == 0 ? 0u : strlen(t) / 2u;
    uint8_t *p = block(len);
    for (i = 0u; i < len; i++) { unsigned b; sscanf(t + 2u * i, "%%2x", &b); p[i] = (uint8_t)b; }
    *n = len;
    return p;
}

static void hex(const uint8_t *p, size_t n)
{
    size_t i;
    if (n == 0u) { fputs(" -", stdout); return; }
    putchar(' ');
    for (i = 0u; i < n; i++) printf("%%02x", p[i]);
}

static void f64(double v) { uint64_t b; memcpy(&b, &v, 8u); printf(" %%016llx", (unsigned long long)b); }
static void f64s(const double *v, size_t n) { size_t i; for (i = 0u; i < n; i++) f64(v[i]); }
static void status(ilcp_status s) { printf("%%s", STATUS[s]); }

/* capacities of payloads (and back-EMF tables) and of frames: `limit P F` sets them (F >= P + 16) */
static size_t cap = 1u << 20, frame_cap = (1u << 20) + ILCP_FRAME_OVERHEAD;
/* an encoder's frame, a heap block of exactly frame_cap bytes, and its payload */
static uint8_t *frame, *payload;

static void open_frame(void) { frame = block(frame_cap); payload = frame + ILCP_HEADER_SIZE; }

/* the frame around the payload of an encoder that returned s (length: read after the encoder ran) */
static void sealed(ilcp_status s, uint16_t type, uint32_t seq, const uint32_t *length)
{
    size_t size = 0u;
    if (s == ILCP_OK) s = ilcp_frame_seal(frame, frame_cap, type, seq, *length, &size);
    status(s);
    hex(frame, size);
    free(frame);
}

int main(void)
{
    size_t size = 0u, got;
    char *text = block(65537u), *line, *end;
    while ((got = fread(text + size, 1u, 65536u, stdin)) > 0u) {
        size += got;
        text = realloc(text, size + 65537u);
        if (!text) return 3;
    }
    text[size] = '\0';
    for (line = text; *line; line = end + 1) {
        char *cmd;
        end = strchr(line, '\n');
        if (!end) return 2;
        *end = '\0';
        cmd = strtok(line, " ");
        if (strncmp(cmd, "enc_", 4u) == 0) open_frame();
        if (strcmp(cmd, "overread") == 0) {
            volatile uint8_t *p = block(1u);
            printf("%%d", p[1]);
        } else if (strcmp(cmd, "limit") == 0) {
            cap = (size_t)u();
            frame_cap = (size_t)u();
            if (frame_cap < cap + ILCP_HEADER_SIZE) return 4;
            printf("OK");
        } else if (strcmp(cmd, "crc") == 0) {
            uint32_t crc = u32();
            size_t n;
            uint8_t *p = bytes(&n);
            printf("%%08lx", (unsigned long)ilcp_crc32_update(crc, p, n));
            free(p);
        } else if (strcmp(cmd, "statuses") == 0) {
            int s;
            for (s = ILCP_OK; s <= ILCP_E_RANGE; s++) printf("%%s%%s=%%lu", s ? " " : "", STATUS[s],
                                                            (unsigned long)ilcp_status_error_code((ilcp_status)s));
        } else if (strcmp(cmd, "bounds") == 0) {
            ilcp_bounds b;
            ilcp_status s;
            uint32_t cpr = u32();
            uint64_t max_samples = u();
            int t;
            ilcp_bounds_any(&b);
            for (t = 1; t <= 8; t++) printf("%%lx ", (unsigned long)b.payload[t]);
            s = ilcp_bounds_target(&b, cpr);
            status(s);
            for (t = 1; s == ILCP_OK && t <= 8; t++) printf(" %%lx", (unsigned long)b.payload[t]);
            printf(" %%lx", (unsigned long)ilcp_data_bound(max_samples));
        } else if (strcmp(cmd, "ranges") == 0) {
            printf("%%lx %%lx %%lx %%lx %%lx %%lx", (unsigned long)ILCP_POLE_PAIRS_MIN,
                   (unsigned long)ILCP_POLE_PAIRS_MAX,
                   (unsigned long)ILCP_SLOTS_MIN, (unsigned long)ILCP_SLOTS_MAX,
                   (unsigned long)ILCP_COUNTS_PER_REV_MIN, (unsigned long)ILCP_COUNTS_PER_REV_MAX);
            f64(ILCP_INERTIA_MIN_KGM2);
            f64(ILCP_INERTIA_MAX_KGM2);
        } else if (strcmp(cmd, "frame") == 0) {
            /* frame any|target|data ARG SEQ BYTES */
            ilcp_bounds b;
            ilcp_header h = {0u, 0u, 0u, 0u};
            const uint8_t *body = NULL;
            char *kind = next();
            uint64_t arg = u();
            uint32_t seq = u32();
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_bounds_any(&b);
            if (strcmp(kind, "target") == 0 && ilcp_bounds_target(&b, (uint32_t)arg) != ILCP_OK) return 4;
            if (strcmp(kind, "data") == 0) b.payload[ILCP_FRAME_DATA] = ilcp_data_bound(arg);
            status(ilcp_frame_decode(p, n, &b, seq, &h, &body));
            printf(" %%x %%x %%lx %%lx %%ld", h.version, h.type, (unsigned long)h.seq, (unsigned long)h.length,
                   body ? (long)(body - p) : -1L);
            free(p);
        } else if (strcmp(cmd, "describe") == 0) {
            ilcp_describe d;
            size_t n;
            uint8_t *p = bytes(&n);
            size_t values = n > ILCP_DESCRIBE_HEAD_SIZE ? (n - ILCP_DESCRIBE_HEAD_SIZE) / 8u : 0u;
            values = values < cap / 8u ? values : cap / 8u;
            double *backemf = block(values * sizeof *backemf);
            ilcp_status s = ilcp_describe_decode(p, n, &d, backemf, values);
            status(s);
            if (s == ILCP_OK) {
                printf(" %%lx %%lx %%lx %%lx", (unsigned long)d.pole_pairs, (unsigned long)d.slots,
                       (unsigned long)d.counts_per_rev, (unsigned long)d.flags);
                f64(d.inertia_kgm2); f64s(d.current_scale, 3u); f64s(d.current_offset, 3u); f64(d.torque_gain);
                f64(d.max_current_a); f64(d.max_torque_nm); f64(d.max_speed_hz);
                f64s(d.backemf_nm_per_a, 3u * (size_t)d.counts_per_rev);
            }
            free(p); free(backemf);
        } else if (strcmp(cmd, "request") == 0) {
            ilcp_request r;
            uint32_t cpr = u32();
            size_t n;
            uint8_t *p = bytes(&n);
            double *ff = block(cpr * sizeof *ff), *exc = block(cpr * sizeof *exc);
            ilcp_status s = ilcp_request_decode(p, n, cpr, &r, ff, exc);
            status(s);
            if (s != ILCP_E_SIZE || n >= ILCP_REQUEST_HEAD_SIZE) printf(" %%lx", (unsigned long)r.trial_id);
            if (s == ILCP_OK) {
                printf(" %%lx %%lx %%lx", (unsigned long)r.revolutions, (unsigned long)r.seed,
                       (unsigned long)r.table_length);
                f64(r.torque_setpoint_nm); f64(r.speed_setpoint_hz); f64s(r.current_scale, 3u);
                f64s(r.current_offset, 3u); f64(r.torque_gain);
                f64s(r.feedforward_nm, cpr); f64s(r.excitation_nm, cpr);
            }
            free(p); free(ff); free(exc);
        } else if (strcmp(cmd, "accept") == 0) {
            ilcp_accept a;
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_status s = ilcp_accept_decode(p, n, &a);
            status(s);
            if (s == ILCP_OK) printf(" %%lx %%llx", (unsigned long)a.trial_id, (unsigned long long)a.max_samples);
            free(p);
        } else if (strcmp(cmd, "heartbeat") == 0) {
            uint32_t id;
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_status s = ilcp_heartbeat_decode(p, n, &id);
            status(s);
            if (s == ILCP_OK) printf(" %%lx", (unsigned long)id);
            free(p);
        } else if (strcmp(cmd, "end") == 0) {
            ilcp_end_of_trial e;
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_status s = ilcp_end_of_trial_decode(p, n, &e);
            status(s);
            if (s == ILCP_OK) printf(" %%lx %%lx %%llx %%lx", (unsigned long)e.trial_id, (unsigned long)e.data_frames,
                                     (unsigned long long)e.n_samples, (unsigned long)e.trial_crc);
            free(p);
        } else if (strcmp(cmd, "error") == 0) {
            ilcp_error e;
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_status s = ilcp_error_decode(p, n, &e);
            status(s);
            if (s == ILCP_OK) {
                printf(" %%lx %%lx", (unsigned long)e.code, (unsigned long)e.trial_id);
                hex(e.message, e.message_length);
            }
            free(p);
        } else if (strcmp(cmd, "data") == 0) {
            ilcp_data_view v;
            size_t n;
            uint8_t *p = bytes(&n);
            ilcp_status s = ilcp_data_decode(p, n, &v);
            status(s);
            if (s == ILCP_OK) {
                const uint8_t *columns[7];
                static const size_t width[7] = {1u, 3u, 1u, 3u, 1u, 3u, 1u};
                size_t j, c;
                columns[0] = v.time_s; columns[1] = v.i_ref_a; columns[2] = v.torque_nm; columns[3] = v.i_meas_a;
                columns[4] = v.torque_true_nm; columns[5] = v.i_true_a; columns[6] = v.speed_true_rad_s;
                printf(" %%lx %%lx %%llx %%lx", (unsigned long)v.trial_id, (unsigned long)v.flags,
                       (unsigned long long)v.first_sample, (unsigned long)v.n);
                for (j = 0u; j < v.n; j++) printf(" %%lld", (long long)ilcp_get_i64(v.count + 8u * j));
                for (c = 0u; c < 7u; c++) {
                    for (j = 0u; columns[c] && j < width[c] * v.n; j++) f64(ilcp_get_f64(columns[c] + 8u * j));
                }
            }
            free(p);
        } else if (strcmp(cmd, "enc_hello") == 0) {
            uint32_t seq = u32(), length = 0u;
            sealed(ILCP_OK, ILCP_FRAME_HELLO, seq, &length);
        } else if (strcmp(cmd, "enc_describe") == 0) {
            ilcp_describe d;
            uint32_t seq = u32(), length = 0u;
            double *backemf;
            d.pole_pairs = u32(); d.slots = u32(); d.counts_per_rev = u32(); d.flags = u32();
            d.inertia_kgm2 = f();
            d.current_scale[0] = f(); d.current_scale[1] = f(); d.current_scale[2] = f();
            d.current_offset[0] = f(); d.current_offset[1] = f(); d.current_offset[2] = f();
            d.torque_gain = f(); d.max_current_a = f(); d.max_torque_nm = f(); d.max_speed_hz = f();
            d.backemf_nm_per_a = backemf = fs(3u * (size_t)d.counts_per_rev);
            sealed(ilcp_describe_encode(&d, payload, cap, &length), ILCP_FRAME_DESCRIBE, seq,
                   &length);
            free(backemf);
        } else if (strcmp(cmd, "enc_request") == 0) {
            ilcp_request r;
            uint32_t seq = u32(), length = 0u;
            double *ff, *exc;
            r.trial_id = u32(); r.revolutions = u32(); r.seed = u32(); r.table_length = u32();
            r.torque_setpoint_nm = f(); r.speed_setpoint_hz = f();
            r.current_scale[0] = f(); r.current_scale[1] = f(); r.current_scale[2] = f();
            r.current_offset[0] = f(); r.current_offset[1] = f(); r.current_offset[2] = f();
            r.torque_gain = f();
            r.feedforward_nm = ff = fs(r.table_length);
            r.excitation_nm = exc = fs(r.table_length);
            sealed(ilcp_request_encode(&r, payload, cap, &length), ILCP_FRAME_REQUEST, seq,
                   &length);
            free(ff); free(exc);
        } else if (strcmp(cmd, "enc_accept") == 0) {
            ilcp_accept a;
            uint32_t seq = u32(), length = 0u;
            a.trial_id = u32(); a.max_samples = u();
            sealed(ilcp_accept_encode(&a, payload, cap, &length), ILCP_FRAME_ACCEPT, seq, &length);
        } else if (strcmp(cmd, "enc_data") == 0) {
            /* enc_data SEQ ID FLAGS FIRST N counts, then each present column in wire order */
            ilcp_data d;
            double *columns[7] = {NULL, NULL, NULL, NULL, NULL, NULL, NULL};
            static const size_t width[7] = {1u, 3u, 1u, 3u, 1u, 3u, 1u};
            int64_t *count;
            uint32_t seq = u32(), length = 0u;
            size_t j, c;
            d.trial_id = u32(); d.flags = u32(); d.first_sample = u(); d.n = u32();
            d.count = count = block(d.n * sizeof *count);
            for (j = 0u; j < d.n; j++) count[j] = (int64_t)u();
            for (c = 0u; c < 7u; c++) {
                if (c < 3u || (d.flags >> (c - 3u)) & 1u) columns[c] = fs(width[c] * d.n);
            }
            d.time_s = columns[0]; d.i_ref_a = columns[1]; d.torque_nm = columns[2]; d.i_meas_a = columns[3];
            d.torque_true_nm = columns[4]; d.i_true_a = columns[5]; d.speed_true_rad_s = columns[6];
            sealed(ilcp_data_encode(&d, payload, cap, &length), ILCP_FRAME_DATA, seq, &length);
            free(count);
            for (c = 0u; c < 7u; c++) free(columns[c]);
        } else if (strcmp(cmd, "enc_heartbeat") == 0) {
            uint32_t seq = u32(), length = 0u;
            sealed(ilcp_heartbeat_encode(u32(), payload, cap, &length), ILCP_FRAME_HEARTBEAT,
                   seq, &length);
        } else if (strcmp(cmd, "enc_end") == 0) {
            ilcp_end_of_trial e;
            uint32_t seq = u32(), length = 0u;
            e.trial_id = u32(); e.data_frames = u32(); e.n_samples = u(); e.trial_crc = u32();
            sealed(ilcp_end_of_trial_encode(&e, payload, cap, &length), ILCP_FRAME_END_OF_TRIAL,
                   seq, &length);
        } else if (strcmp(cmd, "enc_error") == 0) {
            ilcp_error e;
            uint32_t seq = u32(), length = 0u;
            uint8_t *message;
            e.code = u32(); e.trial_id = u32();
            e.message = message = bytes(&e.message_length);
            sealed(ilcp_error_encode(&e, payload, cap, &length), ILCP_FRAME_ERROR, seq, &length);
            free(message);
        } else {
            fprintf(stderr, "unknown command %%s\n", cmd);
            return 2;
        }
        putchar('\n');
    }
    free(text);
    return 0;
}
"""


def _compiler() -> str:
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the C codec of firmware/ cannot be compiled here")
    return compiler


def status_names() -> list[str]:
    """The ilcp_status names in the header's order, without their ILCP_ prefix."""
    header = (FIRMWARE / "ilcpmac_protocol.h").read_text()
    body = re.search(r"typedef enum \{\n([^}]*)\} ilcp_status;", header).group(1)
    return re.findall(r"^\s+ILCP_(\w+)", body, re.M)


@dataclass(frozen=True)
class Driver:
    """The compiled driver: ``run`` feeds it command lines and returns its output lines."""

    binary: Path
    sanitized: bool

    def run(self, commands: list[str]) -> list[str]:
        env = {**os.environ, "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"}
        done = subprocess.run([str(self.binary)], input="".join(c + "\n" for c in commands), capture_output=True,
                              text=True, timeout=60, env=env)
        assert done.returncode == 0 and not done.stderr, done.stderr[-3000:]
        lines = done.stdout.splitlines()
        assert len(lines) == len(commands)
        return lines

    def one(self, command: str) -> list[str]:
        return self.run([command])[0].split()


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> Driver:
    """The codec compiled once with the strict flags alone, then with a driver (sanitized where possible)."""
    compiler = _compiler()
    folder = tmp_path_factory.mktemp("c_protocol")
    source = FIRMWARE / "ilcpmac_protocol.c"
    for level in ("-O0", "-O2"):
        done = subprocess.run([compiler, *STRICT, level, "-c", str(source), "-o", str(folder / "codec.o")],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and not done.stderr, done.stderr
    (folder / "driver.c").write_text(DRIVER % {"statuses": ", ".join(f'"{n}"' for n in status_names())})
    build = [compiler, "-std=c99", "-O1", "-g", "-I", str(FIRMWARE), "-o", str(folder / "driver"),
             str(folder / "driver.c"), str(source)]
    done = subprocess.run([*build, *SANITIZE], capture_output=True, text=True, timeout=120)
    sanitized = done.returncode == 0
    if not sanitized:
        done = subprocess.run(build, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return Driver(folder / "driver", sanitized)


def h(data: bytes) -> str:
    """``data`` as the driver takes bytes."""
    return data.hex() or "-"


def f64(*values: float) -> str:
    """``values`` as the driver takes and prints doubles: their 64 bits in hex."""
    return " ".join(struct.pack("<d", v)[::-1].hex() for v in values)


def floats(tokens: list[str]) -> list[float]:
    """The doubles the driver printed."""
    return [struct.unpack(">d", bytes.fromhex(t))[0] for t in tokens]


def payload_of(parts) -> bytes:
    """The payload of the parts an ``encode_*`` of `ilcpmac.backends.protocol` returns."""
    return b"".join(p if isinstance(p, bytes) else p.tobytes() for p in parts)


def frame_of(ftype: int, payload: bytes = b"", seq: int = 0, version: int = PROTOCOL_VERSION) -> bytes:
    """A frame sealed like `Channel.frame_bytes` seals it, with any type, seq and version."""
    head = HEADER.pack(b"ILCP", version, ftype, seq, len(payload)) + payload
    return head + struct.pack("<I", zlib.crc32(head))


# ---------------------------------------------------------------- the codec itself


def test_the_codec_needs_only_three_standard_headers_and_keeps_no_state():
    header = (FIRMWARE / "ilcpmac_protocol.h").read_text()
    source = (FIRMWARE / "ilcpmac_protocol.c").read_text()
    includes = [line for line in (header + source).splitlines() if line.startswith("#include")]
    assert includes == ["#include <stddef.h>", "#include <stdint.h>", "#include <string.h>",
                        '#include "ilcpmac_protocol.h"']
    assert not re.search(r"\b(malloc|calloc|realloc|free|printf|float)\b", header + source)
    assert re.findall(r"^static (?!const)[^(]*[=;]", source, re.M) == []  # no mutable file-scope variable


def test_the_sanitizers_catch_a_read_one_byte_beyond_a_block(driver):
    if not driver.sanitized:
        pytest.skip("the C compiler has no -fsanitize=address,undefined: the codec's tests ran unsanitized")
    done = subprocess.run([str(driver.binary)], input="overread\n", capture_output=True, text=True, timeout=60,
                          env={**os.environ, "ASAN_OPTIONS": "detect_leaks=0"})
    assert done.returncode != 0 and "heap-buffer-overflow" in done.stderr


def test_crc_check_value_and_piecewise_crc(driver):
    rng = np.random.default_rng(13)
    chunks = [rng.integers(0, 256, n, dtype=np.uint8).tobytes() for n in (0, 1, 7, 1000)]
    commands = ["crc 0 " + h(b"123456789")] + [f"crc 0 {h(c)}" for c in chunks]
    commands += [f"crc {zlib.crc32(chunks[2]):x} {h(chunks[3])}"]
    out = [int(line, 16) for line in driver.run(commands)]
    assert out[0] == 0xCBF43926
    assert out[1:5] == [zlib.crc32(c) for c in chunks]
    assert out[5] == zlib.crc32(chunks[2] + chunks[3])


def test_bounds_ranges_and_error_codes_follow_the_python_protocol(driver):
    out = driver.run(["bounds 1000 80", "bounds 0 0", f"bounds {1 << 20:x} {1 << 40:x}", "ranges", "statuses"])
    first = out[0].split()
    assert [int(v, 16) for v in first[:8]] == [PAYLOAD_BOUNDS[t] for t in FrameType]
    assert first[8] == "OK" and [int(v, 16) for v in first[9:17]] == [target_bounds(0x1000)[t] for t in FrameType]
    assert int(first[17], 16) == data_bound(0x80)
    assert out[1].split()[8:] == ["E_ARGUMENT", "%x" % data_bound(0)]
    # 88 + 16 x 2^20 bytes: no REQUEST of a 2^20-count bench fits the 16 MiB bound
    assert out[2].split()[8:] == ["E_LENGTH", "%x" % MAX_PAYLOAD]
    ranges = out[3].split()
    assert [int(v, 16) for v in ranges[:6]] == [v for key in ("pole_pairs", "slots", "counts_per_rev")
                                                for v in MOTOR_RANGES[key]]
    assert floats(ranges[6:]) == list(MOTOR_RANGES["inertia"])
    codes = dict(item.split("=") for item in out[4].split())
    assert list(codes) == status_names()
    malformed = ["E_TRUNCATED", "E_MAGIC", "E_TYPE", "E_LENGTH", "E_CRC", "E_SEQUENCE", "E_SIZE", "E_FLAGS"]
    assert codes == {"OK": "0", "E_ARGUMENT": str(ErrorCode.INTERNAL), "E_SPACE": str(ErrorCode.INTERNAL),
                     **dict.fromkeys(malformed, str(ErrorCode.MALFORMED_FRAME)),
                     "E_VERSION": str(ErrorCode.VERSION_MISMATCH),
                     **dict.fromkeys(["E_TABLE_LENGTH", "E_NOT_FINITE", "E_RANGE"], str(ErrorCode.BAD_REQUEST))}


# ---------------------------------------------------------------- the worked example of docs/protocol.md


@dataclass(frozen=True)
class Example:
    """The worked example's frames as `ilcpmac.backends.protocol` decodes them."""

    frames: list[DocumentedFrame]
    describe: BenchDescription
    trial_id: int
    request: TrialRequest
    accept: Accept
    chunks: list[tuple[int, int]]  # (first_sample, n) of each DATA frame
    flags: int
    columns: dict[str, np.ndarray]  # the whole trial
    end: EndOfTrial
    error: TargetError


def decoded_example() -> Example:
    frames = documented_frames()
    payloads = [memoryview(f.data[16:-4]) for f in frames]
    trial_id, request = decode_request(payloads[2])
    accept = decode_accept(payloads[3])
    assembler = TrialAssembler(trial_id, accept.max_samples, SampleBounds(accept.max_samples, {}))
    chunks = []
    for payload in payloads[4:6]:
        first = assembler.n_samples
        assembler.add(payload)
        chunks.append((first, assembler.n_samples - first))
    columns = assembler.finish(payloads[6])
    return Example(frames, decode_describe(payloads[1]), trial_id, request, accept, chunks, int(assembler.flags),
                   columns, decode_end(payloads[6]), decode_error(payloads[7]))


def present(flags: int) -> list[str]:
    """The columns a DATA frame of ``flags`` carries, in wire order."""
    return [name for name, _, _, flag in COLUMNS if flag is None or flags & flag]


def data_command(seq: int, trial_id: int, flags: int, first: int, n: int, columns: dict[str, np.ndarray]) -> str:
    counts = " ".join(f"{int(c) & (2**64 - 1):x}" for c in columns["count"][first:first + n])
    values = np.concatenate([columns[name][first:first + n].ravel() for name in present(flags)[1:]])
    return f"enc_data {seq:x} {trial_id:x} {flags:x} {first:x} {n:x} {counts} {f64(*values)}"


def encode_commands(ex: Example) -> list[str]:
    """The driver's commands that encode every frame of the worked example from its fields."""
    seq = [f.seq for f in ex.frames]
    m, cal, lim, r = ex.describe.motor, ex.describe.calibration, ex.describe.limits, ex.request
    return [
        f"enc_hello {seq[0]:x}",
        f"enc_describe {seq[1]:x} {m.pole_pairs:x} {m.slots:x} {m.counts_per_rev:x} {0 if m.torque_sensor else 1:x} "
        + f64(m.inertia_kgm2, *cal.current_scale, *cal.current_offset, cal.torque_gain, lim.max_current_a,
              lim.max_torque_nm, lim.max_speed_hz, *ex.describe.backemf_nm_per_a.ravel()),
        f"enc_request {seq[2]:x} {ex.trial_id:x} {r.revolutions:x} {r.seed:x} {r.feedforward_nm.size:x} "
        + f64(r.torque_setpoint_nm, r.speed_setpoint_hz, *r.calibration.current_scale, *r.calibration.current_offset,
              r.calibration.torque_gain, *r.feedforward_nm, *r.excitation_nm),
        f"enc_accept {seq[3]:x} {ex.accept.trial_id:x} {ex.accept.max_samples:x}",
        *(data_command(s, ex.trial_id, ex.flags, first, n, ex.columns) for s, (first, n) in zip(seq[4:6], ex.chunks)),
        f"enc_end {seq[6]:x} {ex.end.trial_id:x} {ex.end.data_frames:x} {ex.end.n_samples:x} {ex.end.trial_crc:x}",
        f"enc_error {seq[7]:x} {int(ex.error.code):x} {ex.error.trial_id:x} {h(ex.error.detail.encode())}",
    ]


def test_the_c_encoders_write_the_documented_bytes(driver):
    ex = decoded_example()
    for frame, line in zip(ex.frames, driver.run(encode_commands(ex)), strict=True):
        assert line.split() == ["OK", frame.data.hex()], frame.name


def test_the_c_decoders_read_the_documented_bytes(driver):
    ex = decoded_example()
    cpr = ex.describe.motor.counts_per_rev
    bounds = {"client": f"target {cpr:x}", "target": f"data {ex.accept.max_samples:x}"}
    checks = [f"frame {bounds[f.sender]} {f.seq:x} {f.data.hex()}" for f in ex.frames]
    payloads = [h(f.data[16:-4]) for f in ex.frames]
    out = driver.run(checks + [f"describe {payloads[1]}", f"request {cpr:x} {payloads[2]}", f"accept {payloads[3]}",
                               f"data {payloads[4]}", f"data {payloads[5]}", f"end {payloads[6]}",
                               f"error {payloads[7]}"])
    for frame, line in zip(ex.frames, out):
        assert line.split() == ["OK", "1", "%x" % FrameType[frame.name], "%x" % frame.seq,
                                "%x" % (len(frame.data) - 20), "16"], frame.name
    d, m, r = ex.describe, ex.describe.motor, ex.request
    describe = out[8].split()
    assert describe[:5] == ["OK", "8", "30", "4", "0"] and [m.pole_pairs, m.slots, m.counts_per_rev] == [8, 48, 4]
    assert describe[5:] == f64(m.inertia_kgm2, *d.calibration.current_scale, *d.calibration.current_offset,
                               d.calibration.torque_gain, d.limits.max_current_a, d.limits.max_torque_nm,
                               d.limits.max_speed_hz, *d.backemf_nm_per_a.ravel()).split()
    assert out[9].split() == ["OK", "%x" % ex.trial_id, "%x" % r.revolutions, "%x" % r.seed, "%x" % cpr,
                              *f64(r.torque_setpoint_nm, r.speed_setpoint_hz, *r.calibration.current_scale,
                                   *r.calibration.current_offset, r.calibration.torque_gain, *r.feedforward_nm,
                                   *r.excitation_nm).split()]
    assert out[10].split() == ["OK", "%x" % ex.accept.trial_id, "%x" % ex.accept.max_samples]
    for line, (first, n) in zip(out[11:13], ex.chunks):
        expected = data_command(0, ex.trial_id, ex.flags, first, n, ex.columns).split()[2:]
        counts = [str(int(c)) for c in ex.columns["count"][first:first + n]]
        assert line.split() == ["OK", *expected[:4], *counts, *expected[4 + n:]]
    e = ex.end
    assert out[13].split() == ["OK", *("%x" % v for v in (e.trial_id, e.data_frames, e.n_samples, e.trial_crc))]
    assert out[14].split() == ["OK", "%x" % ex.error.code, "%x" % ex.error.trial_id, ex.error.detail.encode().hex()]


def test_every_encoder_refuses_a_buffer_one_byte_short(driver):
    ex = decoded_example()
    commands = encode_commands(ex)
    sizes = [len(f.data) - 20 for f in ex.frames]
    room = 1 << 20  # more than any of them needs
    lines = [c for command, size in zip(commands[1:], sizes[1:])
             for c in (f"limit {size - 1:x} {room:x}", command,  # the encoder refuses
                       f"limit {size:x} {size + 19:x}", command,  # the seal refuses
                       f"limit {size:x} {size + 20:x}", command)]
    describe = h(ex.frames[1].data[16:-4])
    lines += [f"limit {8 * 12 - 1:x} {room:x}", f"describe {describe}", f"limit {8 * 12:x} {room:x}",
              f"describe {describe}"]
    out = [line.split()[0] for line in driver.run(lines)]
    assert out == ["OK", "E_SPACE", "OK", "E_SPACE", "OK", "OK"] * (len(commands) - 1) + ["OK", "E_SPACE", "OK", "OK"]


@pytest.mark.parametrize("flags", [0, 1, 5, 15])
def test_data_of_any_columns_round_trips(driver, flags):
    rng = np.random.default_rng(flags)
    n = 7
    count = np.array([-2**63, -5, -1, 0, 1, 2**40, 2**63 - 1])
    optional = {name: rng.standard_normal((n, 3) if width == 3 else n) for name, width, _, flag in COLUMNS
                if flag is not None and flags & flag}
    trial = TrialData(1.0, 1.0, count, rng.standard_normal(n), rng.standard_normal((n, 3)), rng.standard_normal(n),
                      **optional)
    frames = [payload_of(parts) for _, parts in encode_trial(9, trial, 4)][:-1]
    columns = {name: getattr(trial, name) for name in present(flags)}
    commands = [f"data {p.hex()}" for p in frames] + [data_command(0, 9, flags, first, min(4, n - first), columns)
                                                      for first in (0, 4)]
    out = driver.run(commands)
    for line, first in zip(out, (0, 4)):
        m = min(4, n - first)
        expected = data_command(0, 9, flags, first, m, columns).split()[2:]
        assert line.split() == ["OK", *expected[:4], *(str(int(c)) for c in count[first:first + m]), *expected[4 + m:]]
    for line, payload in zip(out[2:], frames):
        assert line.split() == ["OK", frame_of(FrameType.DATA, payload).hex()]


def test_an_error_message_is_cut_at_a_whole_character(driver):
    message = ("x" * 1023 + "\u00e9\u00e9").encode()  # 1027 bytes: the first e-acute straddles byte 1024
    out = driver.one(f"enc_error 0 4 9 {message.hex()}")
    frame = bytes.fromhex(out[1])
    assert out[0] == "OK" and frame[16:-4] == struct.pack("<II", 4, 9) + b"x" * 1023
    whole = ("x" * 1022 + "\u00e9\u00e9").encode()  # 1026 bytes: byte 1024 starts the second e-acute
    assert bytes.fromhex(driver.one(f"enc_error 0 4 9 {whole.hex()}")[1])[24:-4] == whole[:1024]


# ---------------------------------------------------------------- hostile input


def python_receive(data: bytes, bounds) -> str:
    """What `Channel.recv` makes of ``data`` (then end of stream), as the C codec's status name."""
    a, b = socket.socketpair()
    try:
        a.settimeout(2.0)
        b.settimeout(2.0)
        a.sendall(data)
        a.shutdown(socket.SHUT_WR)
        Channel(b, "the sender", bounds).recv()
        return "OK"
    except ProtocolVersionError:
        return "E_VERSION"
    except ProtocolError as e:
        for pattern, status in (("closed the connection", "E_TRUNCATED"), ("bad magic", "E_MAGIC"),
                                ("unknown frame type", "E_TYPE"), ("announces", "E_LENGTH"),
                                ("CRC mismatch", "E_CRC"), ("sequence gap", "E_SEQUENCE")):
            if pattern in str(e):
                return status
        raise
    finally:
        a.close()
        b.close()


BOUNDS = {"any": PAYLOAD_BOUNDS, "target": target_bounds(CPR), "data": {**PAYLOAD_BOUNDS,
                                                                        FrameType.DATA: data_bound(128)}}
_ARG = {"any": 0, "target": CPR, "data": 128}
_DATA = frame_of(FrameType.DATA, np.arange(8.0).tobytes())
_REQUEST_FRAME = frame_of(FrameType.REQUEST, payload_of(encode_request(1, REQUEST)))


def flipped(frame: bytes, where: int) -> bytes:
    out = bytearray(frame)
    out[where] ^= 0x10
    return bytes(out)


#: hostile byte streams (docs/protocol.md sections 2 and 3; tests/test_protocol*.py): (bytes, bounds, C status)
HOSTILE_FRAMES = {
    "nothing": (b"", "any", "E_TRUNCATED"),
    "bad magic": (b"HTTP" + frame_of(FrameType.HELLO)[4:], "any", "E_MAGIC"),
    "unknown frame type 99": (frame_of(99), "any", "E_TYPE"),
    "unknown frame type 0": (frame_of(0), "target", "E_TYPE"),
    "16 MiB + 1": (HEADER.pack(b"ILCP", 1, FrameType.DATA, 0, MAX_PAYLOAD + 1), "any", "E_LENGTH"),
    "a 16 MiB DATA header after an ACCEPT of 128 samples": (HEADER.pack(b"ILCP", 1, FrameType.DATA, 0, MAX_PAYLOAD),
                                                            "data", "E_LENGTH"),
    **{f"{t.name} one byte beyond the target's bound": (HEADER.pack(b"ILCP", 1, t, 0, target_bounds(CPR)[t] + 1),
                                                        "target", "E_LENGTH") for t in FrameType},
    **{f"{t.name} one byte beyond its type's bound": (HEADER.pack(b"ILCP", 1, t, 0, PAYLOAD_BOUNDS[t] + 1), "any",
                                                      "E_LENGTH") for t in FrameType},
    **{f"cut to {k} bytes": (_DATA[:k], "any", "E_TRUNCATED") for k in (3, 15, 16, 30, len(_DATA) - 1)},
    "half a REQUEST": (_REQUEST_FRAME[:len(_REQUEST_FRAME) // 2], "target", "E_TRUNCATED"),
    **{f"byte {k} flipped": (flipped(_DATA, k), "any", "E_CRC") for k in (5, 10, 16, 40, -1)},
    "DESCRIBE of version 2": (frame_of(FrameType.DESCRIBE, version=2), "any", "E_VERSION"),
    "HELLO of version 0": (frame_of(FrameType.HELLO, version=0), "target", "E_VERSION"),
    "ERROR of version 3": (frame_of(FrameType.ERROR, struct.pack("<II", 1, 0) + b"v3 only", version=3), "target",
                           "OK"),
    "sequence gap": (frame_of(FrameType.DATA, b"next", seq=1), "any", "E_SEQUENCE"),
    "a REQUEST and the next frame's first bytes": (_REQUEST_FRAME + b"ILCP\x01", "target", "OK"),
}


@pytest.mark.parametrize("stream, bounds, status", HOSTILE_FRAMES.values(), ids=HOSTILE_FRAMES.keys())
def test_a_hostile_frame_gets_the_python_verdict(driver, stream, bounds, status):
    out = driver.one(f"frame {bounds} {_ARG[bounds]:x} 0 {h(stream)}")
    assert out[0] == status == python_receive(stream, BOUNDS[bounds])


def _malformed(request) -> bool:
    """Whether ``request`` is no valid request at all (`owned_request` refuses it)."""
    try:
        owned_request(request, 4)
    except MalformedRequest:
        return True
    return False


def request_payload(trial_id: int = 7, **changes) -> bytes:
    return payload_of(encode_request(trial_id, REQUEST.with_changes(**changes)))


def describe_payload(**changes) -> bytes:
    return payload_of(encode_describe(dataclasses.replace(DESCRIPTION, **changes)))


def _calibration(scale=(14.0, 14.0, 14.0), offset=(0.0, 0.0, 0.0), gain=0.908) -> SensorCalibration:
    return SensorCalibration(scale, offset, gain)


def python_verdict(kind: str, payload: bytes) -> str:
    """What `ilcpmac.backends.protocol` makes of a ``kind`` payload: the exception it raises, the ERROR code a
    target answers a REQUEST with, or "ok"."""
    view = memoryview(payload)
    try:
        if kind == "request":
            trial_id, request = decode_request(view)
            answer = check_trial_id(trial_id) or check_request(request, DESCRIPTION)
            return "ok" if answer is None else answer[0].name
        if kind == "data":
            TrialAssembler(int.from_bytes(payload[:4], "little"), 10**6, SampleBounds(10**6, {})).add(view)
        else:
            {"describe": decode_describe, "accept": decode_accept, "heartbeat": decode_heartbeat,
             "end": decode_end, "error": decode_error}[kind](view)
    except ProtocolError:
        return "ProtocolError"
    except BackendError:
        return "BackendError"
    return "ok"


_HEAD = request_payload()[:88]
_ONE_DATA = payload_of(next(encode_trial(7, TrialData(1.0, 1.0, np.arange(3), np.arange(3.0), np.zeros((3, 3)),
                                                      np.ones(3)), 3))[1])

#: hostile payloads: (kind, payload, C status, Python verdict)
HOSTILE_PAYLOADS = {
    "REQUEST of trial 0": ("request", request_payload(trial_id=0), "E_RANGE", "BAD_REQUEST"),
    "REQUEST with tables of 63": ("request", request_payload(feedforward_nm=np.zeros(63), excitation_nm=np.zeros(63)),
                                  "E_TABLE_LENGTH", "BAD_REQUEST"),
    "REQUEST with tables of 65": ("request", request_payload(feedforward_nm=np.zeros(65), excitation_nm=np.zeros(65)),
                                  "E_TABLE_LENGTH", "BAD_REQUEST"),
    "REQUEST with tables of 64 and 63": ("request", request_payload(excitation_nm=np.zeros(63)), "E_SIZE",
                                         "ProtocolError"),
    "REQUEST cut by 257 bytes": ("request", request_payload()[:-257], "E_SIZE", "ProtocolError"),
    "REQUEST shorter than its head": ("request", _HEAD[:87], "E_SIZE", "ProtocolError"),
    "REQUEST with a NaN feed-forward": ("request", request_payload(feedforward_nm=np.full(CPR, np.nan)),
                                        "E_NOT_FINITE", "BAD_REQUEST"),
    "REQUEST with an infinite excitation": ("request", request_payload(excitation_nm=np.r_[np.zeros(63), -np.inf]),
                                            "E_NOT_FINITE", "BAD_REQUEST"),
    "REQUEST with a zero current scale": ("request", request_payload(calibration=_calibration((14.0, 0.0, 14.0))),
                                          "E_RANGE", "BAD_REQUEST"),
    "REQUEST with a NaN current scale": ("request", request_payload(calibration=_calibration((np.nan, 14.0, 14.0))),
                                         "E_NOT_FINITE", "BAD_REQUEST"),
    "REQUEST with an infinite offset": ("request", request_payload(calibration=_calibration(offset=(0, 0, np.inf))),
                                        "E_NOT_FINITE", "BAD_REQUEST"),
    "REQUEST with a negative torque gain": ("request", request_payload(calibration=_calibration(gain=-1.0)),
                                            "E_RANGE", "BAD_REQUEST"),
    "REQUEST of 0 revolutions": ("request", request_payload(revolutions=0), "E_RANGE", "BAD_REQUEST"),
    "REQUEST with a NaN torque": ("request", request_payload(torque_setpoint_nm=np.nan), "E_NOT_FINITE",
                                  "BAD_REQUEST"),
    "REQUEST at 0 Hz": ("request", request_payload(speed_setpoint_hz=0.0), "E_RANGE", "BAD_REQUEST"),
    "REQUEST at -1 Hz": ("request", request_payload(speed_setpoint_hz=-1.0), "E_RANGE", "BAD_REQUEST"),
    "REQUEST at infinite speed": ("request", request_payload(speed_setpoint_hz=np.inf), "E_NOT_FINITE",
                                  "BAD_REQUEST"),
    "REQUEST at NaN Hz": ("request", request_payload(speed_setpoint_hz=np.nan), "E_NOT_FINITE", "BAD_REQUEST"),
    "REQUEST beyond the speed limit (the caller's check)": ("request", request_payload(speed_setpoint_hz=1.6), "OK",
                                                            "LIMIT_EXCEEDED"),
    "DESCRIBE with a negative inertia": ("describe", describe_payload(motor=MotorInfo(8, 48, CPR, -1.0)), "E_RANGE",
                                         "BackendError"),
    "DESCRIBE of 10^6 pole pairs": ("describe", describe_payload(motor=MotorInfo(10**6, 48, CPR, 0.01)), "E_RANGE",
                                    "BackendError"),
    "DESCRIBE of 0 counts": ("describe", describe_payload(motor=MotorInfo(8, 48, 0, 0.01),
                                                          backemf_nm_per_a=np.zeros((0, 3))), "E_RANGE",
                             "BackendError"),
    "DESCRIBE with a NaN current limit": ("describe", describe_payload(limits=BenchLimits(np.nan, 8.0, 1.5)),
                                          "E_NOT_FINITE", "BackendError"),
    "DESCRIBE with a zero current scale": ("describe", describe_payload(calibration=_calibration((14.0, 0.0, 14.0))),
                                           "E_RANGE", "BackendError"),
    "DESCRIBE with an infinite back-EMF": ("describe", describe_payload(backemf_nm_per_a=np.where(
        np.arange(3 * CPR).reshape(CPR, 3) == 7, np.inf, DESCRIPTION.backemf_nm_per_a)), "E_NOT_FINITE",
        "BackendError"),
    "DESCRIBE with an unknown flag": ("describe", describe_payload()[:12] + (2).to_bytes(4, "little")
                                      + describe_payload()[16:], "E_FLAGS", "BackendError"),
    "DESCRIBE one byte short": ("describe", describe_payload()[:-1], "E_SIZE", "ProtocolError"),
    "DESCRIBE shorter than its head": ("describe", describe_payload()[:103], "E_SIZE", "ProtocolError"),
    "ACCEPT of 15 bytes": ("accept", bytes(15), "E_SIZE", "ProtocolError"),
    "ACCEPT of 17 bytes": ("accept", bytes(17), "E_SIZE", "ProtocolError"),
    "HEARTBEAT of 9 bytes": ("heartbeat", bytes(9), "E_SIZE", "ProtocolError"),
    "END_OF_TRIAL of 23 bytes": ("end", bytes(23), "E_SIZE", "ProtocolError"),
    "ERROR of 7 bytes": ("error", bytes(7), "E_SIZE", "ProtocolError"),
    "ERROR of 1033 bytes": ("error", bytes(1033), "E_SIZE", "ProtocolError"),
    "DATA with unknown flags 0x10": ("data", _ONE_DATA[:4] + b"\x10" + _ONE_DATA[5:], "E_FLAGS", "ProtocolError"),
    "DATA of 0 samples": ("data", _ONE_DATA[:16] + bytes(4) + _ONE_DATA[20:24], "E_RANGE", "ProtocolError"),
    "DATA one byte short": ("data", _ONE_DATA[:-1], "E_SIZE", "ProtocolError"),
    "DATA one byte long": ("data", _ONE_DATA + b"\x00", "E_SIZE", "ProtocolError"),
    "DATA shorter than its head": ("data", _ONE_DATA[:23], "E_SIZE", "ProtocolError"),
}


def test_the_hostile_payloads_get_the_python_verdict(driver):
    commands = [f"{kind}{f' {CPR:x}' if kind == 'request' else ''} {h(payload)}"
                for kind, payload, _, _ in HOSTILE_PAYLOADS.values()]
    for (name, (kind, payload, status, verdict)), line in zip(HOSTILE_PAYLOADS.items(), driver.run(commands)):
        out = line.split()
        assert (out[0], python_verdict(kind, payload)) == (status, verdict), name
        if kind == "request" and len(payload) >= 88:
            assert out[1] == ("0" if name == "REQUEST of trial 0" else "7"), name  # a refusal can name the trial


# ---------------------------------------------------------------- property tests: random input, both codecs


#: each example is a batch of inputs for one run of the driver, hence large
BATCHED = settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.large_base_example,
                                                                         HealthCheck.too_slow])


@st.composite
def streams(draw) -> tuple[bytes, str]:
    """Bytes a peer might send: noise, or a frame of any type, version and seq, bit-flipped, cut or followed."""
    bounds = draw(st.sampled_from(list(BOUNDS)))
    if draw(st.integers(0, 4)) == 0:
        return draw(st.binary(max_size=40)), bounds
    payload = draw(st.binary(max_size=draw(st.sampled_from([8, 16, 24, 40, 1100]))))
    data = bytearray(frame_of(draw(st.integers(0, 9)), payload, seq=draw(st.sampled_from([0, 0, 0, 1, 2**32 - 1])),
                              version=draw(st.sampled_from([1, 1, 1, 2]))))
    for index, bit in draw(st.lists(st.tuples(st.integers(0, len(data) - 1), st.integers(0, 7)), max_size=2)):
        data[index] ^= 1 << bit
    tail = draw(st.sampled_from(["whole", "cut", "more"]))
    if tail == "cut":
        return bytes(data[:draw(st.integers(0, len(data) - 1))]), bounds
    return bytes(data) + (draw(st.binary(min_size=1, max_size=8)) if tail == "more" else b""), bounds


@BATCHED
@given(st.lists(streams(), min_size=50, max_size=50))
def test_random_streams_get_the_python_verdict(driver, cases):
    out = driver.run([f"frame {bounds} {_ARG[bounds]:x} 0 {h(data)}" for data, bounds in cases])
    for (data, bounds), line in zip(cases, out):
        status, version, ftype, seq, length, offset = line.split()
        assert status == python_receive(data, BOUNDS[bounds]), data.hex()
        if len(data) >= 16:
            assert [int(v, 16) for v in (version, ftype, seq, length)] == list(struct.unpack_from("<HHII", data, 4))
        if status == "OK":
            assert offset == "16" and len(data) >= 20 + int(length, 16)


_NUMBERS = st.one_of(st.sampled_from([1.0, 0.5, 14.0, 0.908, 2.0]), st.sampled_from([0.0, -0.0, -1.0, 1e300,
                                                                                    5e-324, math.inf, -math.inf,
                                                                                    math.nan]), st.floats())


@st.composite
def request_payloads(draw) -> bytes:
    """REQUEST payloads for a bench of 4 counts: mostly sound, with odd numbers, table lengths and sizes."""
    def number() -> float:
        return draw(_NUMBERS) if draw(st.integers(0, 9)) == 0 else draw(st.sampled_from([0.5, 1.0, 14.0, 0.1]))

    n = draw(st.sampled_from([4, 4, 4, 0, 3, 5]))
    request = TrialRequest(number(), number(), draw(st.sampled_from([1, 2, 0, 2**32 - 1])),
                           np.array([number() for _ in range(n)]), np.array([number() for _ in range(n)]),
                           SensorCalibration([number() for _ in range(3)], [number() for _ in range(3)], number()),
                           seed=draw(st.integers(0, 2**32 - 1)))
    payload = payload_of(encode_request(draw(st.integers(0, 2**32 - 1)), request))
    size = draw(st.sampled_from(["whole", "whole", "cut", "more"]))
    if size == "cut":
        return payload[:draw(st.integers(0, len(payload) - 1))]
    return payload + (b"\x00" * draw(st.integers(1, 16)) if size == "more" else b"")


@BATCHED
@given(st.lists(request_payloads(), min_size=50, max_size=50))
def test_random_requests_get_the_python_verdict(driver, payloads):
    codes = dict(item.split("=") for item in driver.one("statuses"))
    out = driver.run([f"request 4 {h(p)}" for p in payloads])
    description = BenchDescription(MotorInfo(8, 48, 4, 0.01056), np.tile([0.2, -0.1, -0.1], (4, 1)), CAL,
                                   BenchLimits(30.0, 8.0, 1.5))
    for payload, line in zip(payloads, out):
        c = line.split()
        try:
            trial_id, request = decode_request(memoryview(payload))
        except ProtocolError:
            assert c[0] == "E_SIZE"
            continue
        malformed = _malformed(request) or check_trial_id(trial_id) is not None
        assert int(codes[c[0]]) == (ErrorCode.BAD_REQUEST if malformed else 0), (c[0], payload.hex())
        assert int(c[1], 16) == trial_id
        if not malformed:
            cal = request.calibration
            assert c[2:] == ["%x" % request.revolutions, "%x" % request.seed, "4", *f64(
                request.torque_setpoint_nm, request.speed_setpoint_hz, *cal.current_scale, *cal.current_offset,
                cal.torque_gain, *request.feedforward_nm, *request.excitation_nm).split()]
            assert check_request(request, description) is None or check_request(request, description)[0] in (
                ErrorCode.LIMIT_EXCEEDED, ErrorCode.BAD_REQUEST)


_KINDS = ["describe", "request", "accept", "heartbeat", "end", "error", "data"]


@BATCHED
@given(st.lists(st.tuples(st.sampled_from(_KINDS), st.one_of(st.binary(max_size=40), st.binary(max_size=1100))),
                min_size=60, max_size=60))
def test_random_payloads_never_crash_a_decoder_and_get_the_python_verdict(driver, cases):
    out = driver.run([f"{kind}{' 4' if kind == 'request' else ''} {h(payload)}" for kind, payload in cases])
    for (kind, payload), line in zip(cases, out):
        status = line.split()[0]
        verdict = python_verdict(kind, payload)
        if kind == "request":
            verdict = "BAD_REQUEST" if verdict == "ok" and len(payload) != 88 + 16 * 4 else verdict
        expected = {"ProtocolError": {"E_SIZE", "E_FLAGS", "E_RANGE"}, "BackendError": {"E_RANGE", "E_NOT_FINITE"},
                    "BAD_REQUEST": {"E_TABLE_LENGTH", "E_RANGE", "E_NOT_FINITE"}}.get(verdict, {"OK"})
        assert status in expected, (kind, payload.hex(), verdict)
        if kind == "data" and status == "OK":
            flags, n = struct.unpack_from("<I", payload, 4)[0], struct.unpack_from("<I", payload, 16)[0]
            width = sum(w for name, w, _, _ in COLUMNS if name in present(flags))
            assert len(payload) == 24 + 8 * n * width
