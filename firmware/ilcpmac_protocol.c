/*
 * ilcpmac_protocol.c: the frame codec of the ilcpmac bench protocol, version 1 (ilcpmac_protocol.h).
 *
 * C99; no allocation, no state, no I/O. Every length is checked against the buffer it indexes, in 64-bit
 * arithmetic where a product of wire fields could overflow.
 */
#include <string.h>

#include "ilcpmac_protocol.h"

typedef char ilcp_double_is_binary64[sizeof(double) == 8 ? 1 : -1];

static const uint8_t MAGIC[4] = {0x49u, 0x4cu, 0x43u, 0x50u};

/* CRC-32 of every 4-bit value: two lookups per byte */
static const uint32_t CRC_NIBBLE[16] = {
    0x00000000u, 0x1db71064u, 0x3b6e20c8u, 0x26d930acu, 0x76dc4190u, 0x6b6b51f4u, 0x4db26158u, 0x5005713cu,
    0xedb88320u, 0xf00f9344u, 0xd6d6a3e8u, 0xcb61b38cu, 0x9b64c2b0u, 0x86d3d2d4u, 0xa00ae278u, 0xbdbdf21cu,
};

/* ------------------------------------------------------------------ status */

const char *ilcp_status_text(ilcp_status status)
{
    switch (status) {
    case ILCP_OK: return "ok";
    case ILCP_E_ARGUMENT: return "invalid argument (a NULL pointer or an unknown frame type)";
    case ILCP_E_SPACE: return "buffer too small for the message";
    case ILCP_E_TRUNCATED: return "truncated frame";
    case ILCP_E_MAGIC: return "bad magic (not ILCP)";
    case ILCP_E_TYPE: return "unknown frame type";
    case ILCP_E_LENGTH: return "payload length beyond the frame type's bound";
    case ILCP_E_CRC: return "CRC mismatch";
    case ILCP_E_SEQUENCE: return "sequence gap";
    case ILCP_E_VERSION: return "another protocol version";
    case ILCP_E_SIZE: return "payload size does not match its fields";
    case ILCP_E_FLAGS: return "unknown DATA column flags";
    case ILCP_E_TABLE_LENGTH: return "table length is not the bench's counts_per_rev";
    case ILCP_E_NOT_FINITE: return "NaN or infinity where a finite value is required";
    case ILCP_E_RANGE: return "value out of range";
    }
    return "unknown status";
}

uint32_t ilcp_status_error_code(ilcp_status status)
{
    switch (status) {
    case ILCP_OK: return 0u;
    case ILCP_E_VERSION: return ILCP_CODE_VERSION_MISMATCH;
    case ILCP_E_TABLE_LENGTH:
    case ILCP_E_NOT_FINITE:
    case ILCP_E_RANGE: return ILCP_CODE_BAD_REQUEST;
    case ILCP_E_ARGUMENT:
    case ILCP_E_SPACE: return ILCP_CODE_INTERNAL;
    case ILCP_E_TRUNCATED:
    case ILCP_E_MAGIC:
    case ILCP_E_TYPE:
    case ILCP_E_LENGTH:
    case ILCP_E_CRC:
    case ILCP_E_SEQUENCE:
    case ILCP_E_SIZE:
    case ILCP_E_FLAGS: return ILCP_CODE_MALFORMED_FRAME;
    }
    return ILCP_CODE_INTERNAL;
}

/* ------------------------------------------------------------------ little-endian numbers */

void ilcp_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xffu);
    p[1] = (uint8_t)(v >> 8);
}

void ilcp_put_u32(uint8_t *p, uint32_t v)
{
    unsigned k;
    for (k = 0u; k < 4u; k++) {
        p[k] = (uint8_t)((v >> (8u * k)) & 0xffu);
    }
}

void ilcp_put_u64(uint8_t *p, uint64_t v)
{
    unsigned k;
    for (k = 0u; k < 8u; k++) {
        p[k] = (uint8_t)((v >> (8u * k)) & 0xffu);
    }
}

void ilcp_put_i64(uint8_t *p, int64_t v)
{
    ilcp_put_u64(p, (uint64_t)v);
}

void ilcp_put_f64(uint8_t *p, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    ilcp_put_u64(p, bits);
}

uint16_t ilcp_get_u16(const uint8_t *p)
{
    return (uint16_t)((unsigned)p[0] | ((unsigned)p[1] << 8));
}

uint32_t ilcp_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

uint64_t ilcp_get_u64(const uint8_t *p)
{
    return (uint64_t)ilcp_get_u32(p) | ((uint64_t)ilcp_get_u32(p + 4) << 32);
}

int64_t ilcp_get_i64(const uint8_t *p)
{
    uint64_t u = ilcp_get_u64(p);
    /* two's complement without an implementation-defined conversion of values above INT64_MAX */
    return u <= (uint64_t)INT64_MAX ? (int64_t)u : -(int64_t)(~u) - 1;
}

double ilcp_get_f64(const uint8_t *p)
{
    uint64_t bits = ilcp_get_u64(p);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

int ilcp_is_finite(double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    return ((bits >> 52) & 0x7ffu) != 0x7ffu;
}

/* ------------------------------------------------------------------ CRC-32 */

uint32_t ilcp_crc32_update(uint32_t crc, const uint8_t *p, size_t n)
{
    size_t i;
    crc = ~crc;
    for (i = 0u; i < n; i++) {
        crc = (crc >> 4) ^ CRC_NIBBLE[(crc ^ p[i]) & 0xfu];
        crc = (crc >> 4) ^ CRC_NIBBLE[(crc ^ ((uint32_t)p[i] >> 4)) & 0xfu];
    }
    return ~crc;
}

/* ------------------------------------------------------------------ frames */

void ilcp_bounds_any(ilcp_bounds *bounds)
{
    if (bounds == NULL) {
        return;
    }
    bounds->payload[0] = 0u;
    bounds->payload[ILCP_FRAME_HELLO] = 0u;
    bounds->payload[ILCP_FRAME_DESCRIBE] = ILCP_MAX_PAYLOAD;
    bounds->payload[ILCP_FRAME_REQUEST] = ILCP_MAX_PAYLOAD;
    bounds->payload[ILCP_FRAME_ACCEPT] = ILCP_ACCEPT_SIZE;
    bounds->payload[ILCP_FRAME_DATA] = ILCP_MAX_PAYLOAD;
    bounds->payload[ILCP_FRAME_HEARTBEAT] = ILCP_HEARTBEAT_SIZE;
    bounds->payload[ILCP_FRAME_END_OF_TRIAL] = ILCP_END_OF_TRIAL_SIZE;
    bounds->payload[ILCP_FRAME_ERROR] = ILCP_ERROR_HEAD_SIZE + ILCP_MAX_ERROR_MESSAGE;
}

ilcp_status ilcp_bounds_target(ilcp_bounds *bounds, uint32_t counts_per_rev)
{
    uint64_t request = ILCP_REQUEST_HEAD_SIZE + 16u * (uint64_t)counts_per_rev;
    unsigned t;
    if (bounds == NULL || counts_per_rev == 0u) {
        return ILCP_E_ARGUMENT;
    }
    if (request > ILCP_MAX_PAYLOAD) {
        return ILCP_E_LENGTH;
    }
    for (t = 0u; t < 9u; t++) {
        bounds->payload[t] = 0u;
    }
    bounds->payload[ILCP_FRAME_REQUEST] = (uint32_t)request;
    bounds->payload[ILCP_FRAME_ERROR] = ILCP_ERROR_HEAD_SIZE + ILCP_MAX_ERROR_MESSAGE;
    return ILCP_OK;
}

uint32_t ilcp_data_bound(uint64_t max_samples)
{
    uint64_t most = (ILCP_MAX_PAYLOAD - ILCP_DATA_HEAD_SIZE) / (8u * ILCP_MAX_WIDTH);
    if (max_samples > most) {
        return ILCP_MAX_PAYLOAD;
    }
    return (uint32_t)(ILCP_DATA_HEAD_SIZE + 8u * ILCP_MAX_WIDTH * max_samples);
}

ilcp_status ilcp_header_decode(const uint8_t *buf, size_t len, const ilcp_bounds *bounds, ilcp_header *out)
{
    uint32_t bound;
    if (buf == NULL || bounds == NULL || out == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (len < ILCP_HEADER_SIZE) {
        return ILCP_E_TRUNCATED;
    }
    out->version = ilcp_get_u16(buf + 4);
    out->type = ilcp_get_u16(buf + 6);
    out->seq = ilcp_get_u32(buf + 8);
    out->length = ilcp_get_u32(buf + 12);
    if (memcmp(buf, MAGIC, sizeof MAGIC) != 0) {
        return ILCP_E_MAGIC;
    }
    if (out->type < ILCP_FRAME_HELLO || out->type > ILCP_FRAME_ERROR) {
        return ILCP_E_TYPE;
    }
    bound = bounds->payload[out->type];
    if (out->length > bound || out->length > ILCP_MAX_PAYLOAD) {
        return ILCP_E_LENGTH;
    }
    return ILCP_OK;
}

ilcp_status ilcp_frame_decode(const uint8_t *buf, size_t len, const ilcp_bounds *bounds, uint32_t expected_seq,
                              ilcp_header *out, const uint8_t **payload)
{
    ilcp_status status;
    size_t end;
    if (payload == NULL) {
        return ILCP_E_ARGUMENT;
    }
    status = ilcp_header_decode(buf, len, bounds, out);
    if (status != ILCP_OK) {
        return status;
    }
    end = ILCP_HEADER_SIZE + (size_t)out->length;
    if (len - ILCP_HEADER_SIZE < (size_t)out->length + ILCP_CRC_SIZE) {
        return ILCP_E_TRUNCATED;
    }
    *payload = buf + ILCP_HEADER_SIZE;
    if (ilcp_crc32_update(0u, buf, end) != ilcp_get_u32(buf + end)) {
        return ILCP_E_CRC;
    }
    if (out->seq != expected_seq) {
        return ILCP_E_SEQUENCE;
    }
    if (out->version != ILCP_VERSION && out->type != ILCP_FRAME_ERROR) {
        return ILCP_E_VERSION;
    }
    return ILCP_OK;
}

ilcp_status ilcp_header_encode(uint8_t *buf, size_t cap, uint16_t type, uint32_t seq, uint32_t length)
{
    ilcp_bounds any;
    if (buf == NULL || type < ILCP_FRAME_HELLO || type > ILCP_FRAME_ERROR) {
        return ILCP_E_ARGUMENT;
    }
    ilcp_bounds_any(&any);
    if (length > any.payload[type]) {
        return ILCP_E_LENGTH;
    }
    if (cap < ILCP_HEADER_SIZE) {
        return ILCP_E_SPACE;
    }
    memcpy(buf, MAGIC, sizeof MAGIC);
    ilcp_put_u16(buf + 4, (uint16_t)ILCP_VERSION);
    ilcp_put_u16(buf + 6, type);
    ilcp_put_u32(buf + 8, seq);
    ilcp_put_u32(buf + 12, length);
    return ILCP_OK;
}

ilcp_status ilcp_frame_seal(uint8_t *buf, size_t cap, uint16_t type, uint32_t seq, uint32_t length,
                            size_t *frame_size)
{
    ilcp_status status;
    size_t end = ILCP_HEADER_SIZE + (size_t)length;
    if (frame_size == NULL) {
        return ILCP_E_ARGUMENT;
    }
    status = ilcp_header_encode(buf, cap, type, seq, length);
    if (status != ILCP_OK) {
        return status;
    }
    if (cap - ILCP_HEADER_SIZE < (size_t)length + ILCP_CRC_SIZE) {
        return ILCP_E_SPACE;
    }
    ilcp_put_u32(buf + end, ilcp_crc32_update(0u, buf, end));
    *frame_size = end + ILCP_CRC_SIZE;
    return ILCP_OK;
}

/* ------------------------------------------------------------------ payload helpers */

/* The payload of size bytes fits cap and 16 MiB. */
static ilcp_status room(uint64_t size, size_t cap)
{
    if (size > ILCP_MAX_PAYLOAD) {
        return ILCP_E_LENGTH;
    }
    return size > (uint64_t)cap ? ILCP_E_SPACE : ILCP_OK;
}

static void put_f64s(uint8_t *p, const double *v, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        ilcp_put_f64(p + 8u * i, v[i]);
    }
}

static void get_f64s(const uint8_t *p, double *v, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        v[i] = ilcp_get_f64(p + 8u * i);
    }
}

static ilcp_status all_finite(const double *v, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        if (!ilcp_is_finite(v[i])) {
            return ILCP_E_NOT_FINITE;
        }
    }
    return ILCP_OK;
}

/* every value finite and > 0 */
static ilcp_status all_positive(const double *v, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        if (!ilcp_is_finite(v[i])) {
            return ILCP_E_NOT_FINITE;
        }
        if (!(v[i] > 0.0)) {
            return ILCP_E_RANGE;
        }
    }
    return ILCP_OK;
}

/* the first failure of a sequence of checks */
#define CHECK(expression)                  \
    do {                                   \
        ilcp_status check_ = (expression); \
        if (check_ != ILCP_OK) {           \
            return check_;                 \
        }                                  \
    } while (0)

/* ------------------------------------------------------------------ DESCRIBE */

/* 5.1: what a client refuses, the back-EMF table aside */
static ilcp_status describe_check(const ilcp_describe *d)
{
    if ((d->flags & ~ILCP_DESCRIBE_NO_TORQUE_SENSOR) != 0u) {
        return ILCP_E_FLAGS;
    }
    if (d->pole_pairs < ILCP_POLE_PAIRS_MIN || d->pole_pairs > ILCP_POLE_PAIRS_MAX
        || d->slots < ILCP_SLOTS_MIN || d->slots > ILCP_SLOTS_MAX
        || d->counts_per_rev < ILCP_COUNTS_PER_REV_MIN || d->counts_per_rev > ILCP_COUNTS_PER_REV_MAX) {
        return ILCP_E_RANGE;
    }
    CHECK(all_finite(&d->inertia_kgm2, 1u));
    if (!(d->inertia_kgm2 >= ILCP_INERTIA_MIN_KGM2 && d->inertia_kgm2 <= ILCP_INERTIA_MAX_KGM2)) {
        return ILCP_E_RANGE;
    }
    CHECK(all_positive(d->current_scale, 3u));
    CHECK(all_positive(&d->torque_gain, 1u));
    CHECK(all_positive(&d->max_current_a, 1u));
    CHECK(all_positive(&d->max_torque_nm, 1u));
    CHECK(all_positive(&d->max_speed_hz, 1u));
    return all_finite(d->current_offset, 3u);
}

ilcp_status ilcp_describe_encode(const ilcp_describe *describe, uint8_t *payload, size_t cap, uint32_t *length)
{
    const ilcp_describe *d = describe;
    uint64_t size;
    if (d == NULL || payload == NULL || length == NULL || d->backemf_nm_per_a == NULL) {
        return ILCP_E_ARGUMENT;
    }
    CHECK(describe_check(d));
    CHECK(all_finite(d->backemf_nm_per_a, 3u * (size_t)d->counts_per_rev));
    size = ILCP_DESCRIBE_HEAD_SIZE + 24u * (uint64_t)d->counts_per_rev;
    CHECK(room(size, cap));
    ilcp_put_u32(payload, d->pole_pairs);
    ilcp_put_u32(payload + 4, d->slots);
    ilcp_put_u32(payload + 8, d->counts_per_rev);
    ilcp_put_u32(payload + 12, d->flags);
    ilcp_put_f64(payload + 16, d->inertia_kgm2);
    put_f64s(payload + 24, d->current_scale, 3u);
    put_f64s(payload + 48, d->current_offset, 3u);
    ilcp_put_f64(payload + 72, d->torque_gain);
    ilcp_put_f64(payload + 80, d->max_current_a);
    ilcp_put_f64(payload + 88, d->max_torque_nm);
    ilcp_put_f64(payload + 96, d->max_speed_hz);
    put_f64s(payload + ILCP_DESCRIBE_HEAD_SIZE, d->backemf_nm_per_a, 3u * (size_t)d->counts_per_rev);
    *length = (uint32_t)size;
    return ILCP_OK;
}

ilcp_status ilcp_describe_decode(const uint8_t *payload, size_t length, ilcp_describe *out,
                                 double *backemf_nm_per_a, size_t backemf_cap)
{
    size_t values;
    if (payload == NULL || out == NULL || backemf_nm_per_a == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length < ILCP_DESCRIBE_HEAD_SIZE) {
        return ILCP_E_SIZE;
    }
    out->pole_pairs = ilcp_get_u32(payload);
    out->slots = ilcp_get_u32(payload + 4);
    out->counts_per_rev = ilcp_get_u32(payload + 8);
    out->flags = ilcp_get_u32(payload + 12);
    out->inertia_kgm2 = ilcp_get_f64(payload + 16);
    get_f64s(payload + 24, out->current_scale, 3u);
    get_f64s(payload + 48, out->current_offset, 3u);
    out->torque_gain = ilcp_get_f64(payload + 72);
    out->max_current_a = ilcp_get_f64(payload + 80);
    out->max_torque_nm = ilcp_get_f64(payload + 88);
    out->max_speed_hz = ilcp_get_f64(payload + 96);
    out->backemf_nm_per_a = backemf_nm_per_a;
    if ((uint64_t)length != ILCP_DESCRIBE_HEAD_SIZE + 24u * (uint64_t)out->counts_per_rev) {
        return ILCP_E_SIZE;
    }
    CHECK(describe_check(out));
    values = 3u * (size_t)out->counts_per_rev;
    if (backemf_cap < values) {
        return ILCP_E_SPACE;
    }
    get_f64s(payload + ILCP_DESCRIBE_HEAD_SIZE, backemf_nm_per_a, values);
    return all_finite(backemf_nm_per_a, values);
}

/* ------------------------------------------------------------------ REQUEST */

/* section 6 on a single request, after its table length */
static ilcp_status request_check(const ilcp_request *r)
{
    CHECK(all_finite(r->feedforward_nm, r->table_length));
    CHECK(all_finite(r->excitation_nm, r->table_length));
    CHECK(all_positive(r->current_scale, 3u));
    CHECK(all_finite(r->current_offset, 3u));
    CHECK(all_positive(&r->torque_gain, 1u));
    if (r->revolutions < 1u) {
        return ILCP_E_RANGE;
    }
    CHECK(all_finite(&r->torque_setpoint_nm, 1u));
    return all_positive(&r->speed_setpoint_hz, 1u);
}

ilcp_status ilcp_request_encode(const ilcp_request *request, uint8_t *payload, size_t cap, uint32_t *length)
{
    const ilcp_request *r = request;
    uint64_t size;
    if (r == NULL || payload == NULL || length == NULL || r->feedforward_nm == NULL || r->excitation_nm == NULL) {
        return ILCP_E_ARGUMENT;
    }
    CHECK(request_check(r));
    size = ILCP_REQUEST_HEAD_SIZE + 16u * (uint64_t)r->table_length;
    CHECK(room(size, cap));
    ilcp_put_u32(payload, r->trial_id);
    ilcp_put_u32(payload + 4, r->revolutions);
    ilcp_put_u32(payload + 8, r->seed);
    ilcp_put_u32(payload + 12, r->table_length);
    ilcp_put_f64(payload + 16, r->torque_setpoint_nm);
    ilcp_put_f64(payload + 24, r->speed_setpoint_hz);
    put_f64s(payload + 32, r->current_scale, 3u);
    put_f64s(payload + 56, r->current_offset, 3u);
    ilcp_put_f64(payload + 80, r->torque_gain);
    put_f64s(payload + ILCP_REQUEST_HEAD_SIZE, r->feedforward_nm, r->table_length);
    put_f64s(payload + ILCP_REQUEST_HEAD_SIZE + 8u * (size_t)r->table_length, r->excitation_nm, r->table_length);
    *length = (uint32_t)size;
    return ILCP_OK;
}

ilcp_status ilcp_request_decode(const uint8_t *payload, size_t length, uint32_t counts_per_rev, ilcp_request *out,
                                double *feedforward_nm, double *excitation_nm)
{
    uint32_t n;
    if (payload == NULL || out == NULL || feedforward_nm == NULL || excitation_nm == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length < ILCP_REQUEST_HEAD_SIZE) {
        return ILCP_E_SIZE;
    }
    out->trial_id = ilcp_get_u32(payload);
    out->revolutions = ilcp_get_u32(payload + 4);
    out->seed = ilcp_get_u32(payload + 8);
    out->table_length = n = ilcp_get_u32(payload + 12);
    out->torque_setpoint_nm = ilcp_get_f64(payload + 16);
    out->speed_setpoint_hz = ilcp_get_f64(payload + 24);
    get_f64s(payload + 32, out->current_scale, 3u);
    get_f64s(payload + 56, out->current_offset, 3u);
    out->torque_gain = ilcp_get_f64(payload + 80);
    out->feedforward_nm = feedforward_nm;
    out->excitation_nm = excitation_nm;
    if ((uint64_t)length != ILCP_REQUEST_HEAD_SIZE + 16u * (uint64_t)n) {
        return ILCP_E_SIZE;
    }
    if (out->trial_id < 1u) { /* section 5.2: 0 names no trial in an ERROR */
        return ILCP_E_RANGE;
    }
    if (n != counts_per_rev) {
        return ILCP_E_TABLE_LENGTH;
    }
    get_f64s(payload + ILCP_REQUEST_HEAD_SIZE, feedforward_nm, n);
    get_f64s(payload + ILCP_REQUEST_HEAD_SIZE + 8u * (size_t)n, excitation_nm, n);
    return request_check(out);
}

/* ------------------------------------------------------------------ ACCEPT, HEARTBEAT, END_OF_TRIAL */

ilcp_status ilcp_accept_encode(const ilcp_accept *accept, uint8_t *payload, size_t cap, uint32_t *length)
{
    if (accept == NULL || payload == NULL || length == NULL) {
        return ILCP_E_ARGUMENT;
    }
    CHECK(room(ILCP_ACCEPT_SIZE, cap));
    ilcp_put_u32(payload, accept->trial_id);
    ilcp_put_u32(payload + 4, 0u);
    ilcp_put_u64(payload + 8, accept->max_samples);
    *length = ILCP_ACCEPT_SIZE;
    return ILCP_OK;
}

ilcp_status ilcp_accept_decode(const uint8_t *payload, size_t length, ilcp_accept *out)
{
    if (payload == NULL || out == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length != ILCP_ACCEPT_SIZE) {
        return ILCP_E_SIZE;
    }
    out->trial_id = ilcp_get_u32(payload);
    out->max_samples = ilcp_get_u64(payload + 8);
    return ILCP_OK;
}

ilcp_status ilcp_heartbeat_encode(uint32_t trial_id, uint8_t *payload, size_t cap, uint32_t *length)
{
    if (payload == NULL || length == NULL) {
        return ILCP_E_ARGUMENT;
    }
    CHECK(room(ILCP_HEARTBEAT_SIZE, cap));
    ilcp_put_u32(payload, trial_id);
    ilcp_put_u32(payload + 4, 0u);
    *length = ILCP_HEARTBEAT_SIZE;
    return ILCP_OK;
}

ilcp_status ilcp_heartbeat_decode(const uint8_t *payload, size_t length, uint32_t *trial_id)
{
    if (payload == NULL || trial_id == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length != ILCP_HEARTBEAT_SIZE) {
        return ILCP_E_SIZE;
    }
    *trial_id = ilcp_get_u32(payload);
    return ILCP_OK;
}

ilcp_status ilcp_end_of_trial_encode(const ilcp_end_of_trial *end, uint8_t *payload, size_t cap,
                                     uint32_t *length)
{
    if (end == NULL || payload == NULL || length == NULL) {
        return ILCP_E_ARGUMENT;
    }
    CHECK(room(ILCP_END_OF_TRIAL_SIZE, cap));
    ilcp_put_u32(payload, end->trial_id);
    ilcp_put_u32(payload + 4, end->data_frames);
    ilcp_put_u64(payload + 8, end->n_samples);
    ilcp_put_u32(payload + 16, end->trial_crc);
    ilcp_put_u32(payload + 20, 0u);
    *length = ILCP_END_OF_TRIAL_SIZE;
    return ILCP_OK;
}

ilcp_status ilcp_end_of_trial_decode(const uint8_t *payload, size_t length, ilcp_end_of_trial *out)
{
    if (payload == NULL || out == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length != ILCP_END_OF_TRIAL_SIZE) {
        return ILCP_E_SIZE;
    }
    out->trial_id = ilcp_get_u32(payload);
    out->data_frames = ilcp_get_u32(payload + 4);
    out->n_samples = ilcp_get_u64(payload + 8);
    out->trial_crc = ilcp_get_u32(payload + 16);
    return ILCP_OK;
}

/* ------------------------------------------------------------------ DATA */

/* width of each column in wire order; the optional ones carry flag 1 << (index - 4) */
static const uint32_t COLUMN_WIDTH[8] = {1u, 1u, 3u, 1u, 3u, 1u, 3u, 1u};

static int column_present(uint32_t flags, unsigned column)
{
    return column < 4u || ((flags >> (column - 4u)) & 1u) != 0u;
}

uint32_t ilcp_data_width(uint32_t flags)
{
    uint32_t width = 0u;
    unsigned c;
    if ((flags & ~ILCP_ALL_COLUMNS) != 0u) {
        return 0u;
    }
    for (c = 0u; c < 8u; c++) {
        if (column_present(flags, c)) {
            width += COLUMN_WIDTH[c];
        }
    }
    return width;
}

/* The size of a DATA payload of n samples with flags. */
static ilcp_status data_size(uint32_t flags, uint32_t n, uint64_t *size)
{
    uint32_t width = ilcp_data_width(flags);
    if (width == 0u) {
        return ILCP_E_FLAGS;
    }
    if (n == 0u) {
        return ILCP_E_RANGE;
    }
    *size = ILCP_DATA_HEAD_SIZE + 8u * (uint64_t)n * width;
    return ILCP_OK;
}

ilcp_status ilcp_data_encode(const ilcp_data *data, uint8_t *payload, size_t cap, uint32_t *length)
{
    const double *columns[8];
    uint64_t size;
    uint8_t *p;
    size_t i;
    unsigned c;
    if (data == NULL || payload == NULL || length == NULL || data->count == NULL) {
        return ILCP_E_ARGUMENT;
    }
    columns[0] = NULL;
    columns[1] = data->time_s;
    columns[2] = data->i_ref_a;
    columns[3] = data->torque_nm;
    columns[4] = data->i_meas_a;
    columns[5] = data->torque_true_nm;
    columns[6] = data->i_true_a;
    columns[7] = data->speed_true_rad_s;
    CHECK(data_size(data->flags, data->n, &size));
    for (c = 1u; c < 8u; c++) {
        if (column_present(data->flags, c) && columns[c] == NULL) {
            return ILCP_E_ARGUMENT;
        }
    }
    CHECK(room(size, cap));
    ilcp_put_u32(payload, data->trial_id);
    ilcp_put_u32(payload + 4, data->flags);
    ilcp_put_u64(payload + 8, data->first_sample);
    ilcp_put_u32(payload + 16, data->n);
    ilcp_put_u32(payload + 20, 0u);
    p = payload + ILCP_DATA_HEAD_SIZE;
    for (i = 0u; i < data->n; i++) {
        ilcp_put_i64(p + 8u * i, data->count[i]);
    }
    p += 8u * (size_t)data->n;
    for (c = 1u; c < 8u; c++) {
        if (column_present(data->flags, c)) {
            size_t values = (size_t)COLUMN_WIDTH[c] * data->n;
            put_f64s(p, columns[c], values);
            p += 8u * values;
        }
    }
    *length = (uint32_t)size;
    return ILCP_OK;
}

ilcp_status ilcp_data_decode(const uint8_t *payload, size_t length, ilcp_data_view *out)
{
    const uint8_t **columns[8];
    const uint8_t *p;
    uint64_t size;
    unsigned c;
    if (payload == NULL || out == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length < ILCP_DATA_HEAD_SIZE) {
        return ILCP_E_SIZE;
    }
    out->trial_id = ilcp_get_u32(payload);
    out->flags = ilcp_get_u32(payload + 4);
    out->first_sample = ilcp_get_u64(payload + 8);
    out->n = ilcp_get_u32(payload + 16);
    columns[0] = &out->count;
    columns[1] = &out->time_s;
    columns[2] = &out->i_ref_a;
    columns[3] = &out->torque_nm;
    columns[4] = &out->i_meas_a;
    columns[5] = &out->torque_true_nm;
    columns[6] = &out->i_true_a;
    columns[7] = &out->speed_true_rad_s;
    for (c = 0u; c < 8u; c++) {
        *columns[c] = NULL;
    }
    CHECK(data_size(out->flags, out->n, &size));
    if ((uint64_t)length != size) {
        return ILCP_E_SIZE;
    }
    p = payload + ILCP_DATA_HEAD_SIZE;
    for (c = 0u; c < 8u; c++) {
        if (column_present(out->flags, c)) {
            *columns[c] = p;
            p += 8u * (size_t)COLUMN_WIDTH[c] * out->n;
        }
    }
    return ILCP_OK;
}

/* ------------------------------------------------------------------ ERROR */

/* The longest prefix of text[0..n-1] of at most max bytes that does not end inside a UTF-8 character. */
static size_t utf8_cut(const uint8_t *text, size_t n, size_t max)
{
    size_t cut, lead, need;
    if (n <= max) {
        return n;
    }
    cut = max;
    lead = cut;
    while (lead > 0u && lead > cut - 3u && (text[lead - 1u] & 0xc0u) == 0x80u) {
        lead--;
    }
    if (lead == 0u) {
        return cut;
    }
    lead--;
    need = text[lead] >= 0xf0u ? 4u : text[lead] >= 0xe0u ? 3u : text[lead] >= 0xc0u ? 2u : 1u;
    return lead + need > cut ? lead : cut;
}

ilcp_status ilcp_error_encode(const ilcp_error *error, uint8_t *payload, size_t cap, uint32_t *length)
{
    size_t m;
    if (error == NULL || payload == NULL || length == NULL || (error->message == NULL && error->message_length > 0u)) {
        return ILCP_E_ARGUMENT;
    }
    m = error->message_length == 0u ? 0u : utf8_cut(error->message, error->message_length, ILCP_MAX_ERROR_MESSAGE);
    CHECK(room(ILCP_ERROR_HEAD_SIZE + (uint64_t)m, cap));
    ilcp_put_u32(payload, error->code);
    ilcp_put_u32(payload + 4, error->trial_id);
    if (m > 0u) {
        memcpy(payload + ILCP_ERROR_HEAD_SIZE, error->message, m);
    }
    *length = (uint32_t)(ILCP_ERROR_HEAD_SIZE + m);
    return ILCP_OK;
}

ilcp_status ilcp_error_decode(const uint8_t *payload, size_t length, ilcp_error *out)
{
    if (payload == NULL || out == NULL) {
        return ILCP_E_ARGUMENT;
    }
    if (length < ILCP_ERROR_HEAD_SIZE || length > ILCP_ERROR_HEAD_SIZE + ILCP_MAX_ERROR_MESSAGE) {
        return ILCP_E_SIZE;
    }
    out->code = ilcp_get_u32(payload);
    out->trial_id = ilcp_get_u32(payload + 4);
    out->message = payload + ILCP_ERROR_HEAD_SIZE;
    out->message_length = length - ILCP_ERROR_HEAD_SIZE;
    return ILCP_OK;
}
