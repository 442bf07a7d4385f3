/*
 * ilcpmac_protocol.h: the frame codec of the ilcpmac bench protocol, version 1.
 *
 * docs/protocol.md of ilcpmac is the specification; section numbers below are its own. This codec turns
 * frames and payloads into fields and back, and checks everything a single frame can be checked for. It
 * does no I/O, keeps no state, allocates nothing and needs only <stdint.h>, <stddef.h> and <string.h>:
 * every function works in buffers the caller owns, given with their capacities, and returns an
 * ilcp_status. Whatever the bytes received, no function reads or writes outside the buffers it is given.
 * Multi-byte fields are little-endian on the wire whatever the host's byte order; doubles must be IEEE 754
 * binary64 with the byte order of uint64_t (every current C99 target).
 */
#ifndef ILCPMAC_PROTOCOL_H
#define ILCPMAC_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------ sizes and bounds (sections 2, 3, 5) */

#define ILCP_VERSION 1u
#define ILCP_HEADER_SIZE 16u
#define ILCP_CRC_SIZE 4u
/* header + CRC: a frame is ILCP_FRAME_OVERHEAD + length bytes */
#define ILCP_FRAME_OVERHEAD 20u
/* largest payload of any frame, bytes (16 MiB) */
#define ILCP_MAX_PAYLOAD 16777216u
#define ILCP_MAX_ERROR_MESSAGE 1024u

#define ILCP_DESCRIBE_HEAD_SIZE 104u
#define ILCP_REQUEST_HEAD_SIZE 88u
#define ILCP_ACCEPT_SIZE 16u
#define ILCP_DATA_HEAD_SIZE 24u
#define ILCP_HEARTBEAT_SIZE 8u
#define ILCP_END_OF_TRIAL_SIZE 24u
#define ILCP_ERROR_HEAD_SIZE 8u

/* DESCRIBE's [motor] data must lie in these ranges (the bench format's, docs/bench-format.md) */
#define ILCP_POLE_PAIRS_MIN 1u
#define ILCP_POLE_PAIRS_MAX 256u
#define ILCP_SLOTS_MIN 3u
#define ILCP_SLOTS_MAX 2048u
#define ILCP_COUNTS_PER_REV_MIN 4u
#define ILCP_COUNTS_PER_REV_MAX 1048576u
#define ILCP_INERTIA_MIN_KGM2 1e-8
#define ILCP_INERTIA_MAX_KGM2 1e4

/* ------------------------------------------------------------------ enumerations (sections 3, 5.4, 7) */

typedef enum {
    ILCP_FRAME_HELLO = 1,
    ILCP_FRAME_DESCRIBE = 2,
    ILCP_FRAME_REQUEST = 3,
    ILCP_FRAME_ACCEPT = 4,
    ILCP_FRAME_DATA = 5,
    ILCP_FRAME_HEARTBEAT = 6,
    ILCP_FRAME_END_OF_TRIAL = 7,
    ILCP_FRAME_ERROR = 8
} ilcp_frame_type;

/* the codes of ERROR frames */
typedef enum {
    ILCP_CODE_VERSION_MISMATCH = 1,
    ILCP_CODE_MALFORMED_FRAME = 2,
    ILCP_CODE_UNEXPECTED_FRAME = 3,
    ILCP_CODE_BAD_REQUEST = 4,
    ILCP_CODE_LIMIT_EXCEEDED = 5,
    ILCP_CODE_TRIAL_FAILED = 6,
    ILCP_CODE_BUSY = 7,
    ILCP_CODE_INTERNAL = 8
} ilcp_error_code;

/* the DATA flags of the optional columns; the other bits must be 0 */
typedef enum {
    ILCP_COL_I_MEAS = 1,
    ILCP_COL_TORQUE_TRUE = 2,
    ILCP_COL_I_TRUE = 4,
    ILCP_COL_SPEED_TRUE = 8
} ilcp_column_flag;
#define ILCP_ALL_COLUMNS 0xFu
/* values per sample with every column present */
#define ILCP_MAX_WIDTH 14u

/* What a call found. ilcp_status_error_code gives the ERROR code a target answers with. */
typedef enum {
    ILCP_OK = 0,
    ILCP_E_ARGUMENT,     /* a NULL pointer or a frame type that does not exist: the caller's bug */
    ILCP_E_SPACE,        /* the caller's buffer is too small for the message */
    ILCP_E_TRUNCATED,    /* fewer bytes than the header or frame: read more (at the end of the stream: truncated) */
    ILCP_E_MAGIC,        /* the frame does not start with ILCP */
    ILCP_E_TYPE,         /* unknown frame type */
    ILCP_E_LENGTH,       /* a payload length beyond its frame type's bound (section 3) or 16 MiB */
    ILCP_E_CRC,          /* the CRC does not match */
    ILCP_E_SEQUENCE,     /* seq is not the next expected number */
    ILCP_E_VERSION,      /* a frame other than ERROR in another protocol version */
    ILCP_E_SIZE,         /* a payload size other than its type and fields make it */
    ILCP_E_FLAGS,        /* DATA column flags beyond ILCP_ALL_COLUMNS */
    ILCP_E_TABLE_LENGTH, /* a REQUEST table_length other than the target's counts_per_rev */
    ILCP_E_NOT_FINITE,   /* NaN or infinity where a finite value is required */
    ILCP_E_RANGE         /* a finite value out of its range: revolutions 0, a speed, scale, gain or limit <= 0,
                            DESCRIBE motor data outside the ILCP_..._MIN/MAX ranges, a DATA frame of 0 samples */
} ilcp_status;

/* One line naming what went wrong (a constant string: fit for a log or an ERROR message). */
const char *ilcp_status_text(ilcp_status status);

/* The ERROR code a target answers a frame or REQUEST that failed with status (section 7), 0 for ILCP_OK:
 * VERSION_MISMATCH, MALFORMED_FRAME (then close), BAD_REQUEST (section 6), INTERNAL (E_ARGUMENT, E_SPACE). */
uint32_t ilcp_status_error_code(ilcp_status status);

/* ------------------------------------------------------------------ little-endian numbers (section 1) */

/* Byte by byte: p must hold 2, 4 or 8 bytes; no alignment needed. */
void ilcp_put_u16(uint8_t *p, uint16_t v);
void ilcp_put_u32(uint8_t *p, uint32_t v);
void ilcp_put_u64(uint8_t *p, uint64_t v);
void ilcp_put_i64(uint8_t *p, int64_t v);
void ilcp_put_f64(uint8_t *p, double v);
uint16_t ilcp_get_u16(const uint8_t *p);
uint32_t ilcp_get_u32(const uint8_t *p);
uint64_t ilcp_get_u64(const uint8_t *p);
int64_t ilcp_get_i64(const uint8_t *p);
double ilcp_get_f64(const uint8_t *p);

/* 1 if v is neither NaN nor infinite (decided on its bits: no <math.h>) */
int ilcp_is_finite(double v);

/* ------------------------------------------------------------------ CRC-32 (section 2) */

/* CRC-32/ISO-HDLC (zlib's) of crc's message followed by p[0..n-1]; start with crc = 0. A 16-entry table. */
uint32_t ilcp_crc32_update(uint32_t crc, const uint8_t *p, size_t n);

/* ------------------------------------------------------------------ frames (section 2) */

typedef struct {
    uint16_t version;
    uint16_t type;   /* an ilcp_frame_type once decoded without E_MAGIC or E_TYPE */
    uint32_t seq;
    uint32_t length; /* payload bytes */
} ilcp_header;

/* The largest payload accepted per frame type, bytes, indexed by ilcp_frame_type (index 0 unused). A receiver
 * may lower an entry once it knows more (a client: the DATA bound after ACCEPT, ilcp_data_bound). */
typedef struct {
    uint32_t payload[9];
} ilcp_bounds;

/* The bounds of section 3 as far as the frame type alone fixes them (16 MiB for DESCRIBE, REQUEST, DATA). */
void ilcp_bounds_any(ilcp_bounds *bounds);

/* What a target of counts_per_rev counts receives: HELLO (empty), REQUEST (88 + 16 counts_per_rev), ERROR;
 * 0 for the types only a target sends. E_ARGUMENT for counts_per_rev 0, E_LENGTH if no REQUEST fits 16 MiB. */
ilcp_status ilcp_bounds_target(ilcp_bounds *bounds, uint32_t counts_per_rev);

/* The largest DATA payload of a trial of at most max_samples samples (every column present), at most 16 MiB. */
uint32_t ilcp_data_bound(uint64_t max_samples);

/* Steps 1 to 3 of receiving a frame: magic, known type, length within its bound, on the first len bytes of
 * buf (E_TRUNCATED below 16). Then read ILCP_CRC_SIZE + out->length more bytes and call ilcp_frame_decode.
 * *out holds the header's fields whenever len >= 16, whatever the status. */
ilcp_status ilcp_header_decode(const uint8_t *buf, size_t len, const ilcp_bounds *bounds, ilcp_header *out);

/* Every step of receiving a frame, in order: ilcp_header_decode, the whole frame present (E_TRUNCATED),
 * CRC, seq equal to expected_seq, version 1 unless the frame is an ERROR. *payload points at the payload
 * inside buf (out->length bytes); buf may hold more bytes after the frame (the next frame's). *out and
 * *payload are set whenever len >= 16 and the whole frame is present, so that after E_VERSION the caller
 * still knows the frame's type; on E_VERSION and E_SEQUENCE the CRC has matched. */
ilcp_status ilcp_frame_decode(const uint8_t *buf, size_t len, const ilcp_bounds *bounds, uint32_t expected_seq,
                              ilcp_header *out, const uint8_t **payload);

/* The 16-byte header of a frame of version 1 into buf (cap bytes). E_LENGTH beyond the type's bound. */
ilcp_status ilcp_header_encode(uint8_t *buf, size_t cap, uint16_t type, uint32_t seq, uint32_t length);

/* Seal a frame whose payload (length bytes) the caller has put at buf + ILCP_HEADER_SIZE: writes the header
 * before it and the CRC after it; *frame_size = ILCP_FRAME_OVERHEAD + length bytes to send. For a frame too
 * large for memory, send ilcp_header_encode's header and the payload piece by piece instead, computing the
 * CRC with ilcp_crc32_update as they go, and send the CRC last (ilcp_put_u32). */
ilcp_status ilcp_frame_seal(uint8_t *buf, size_t cap, uint16_t type, uint32_t seq, uint32_t length,
                            size_t *frame_size);

/* ------------------------------------------------------------------ payloads (sections 5 and 6)
 *
 * X_encode writes the payload into payload[0..cap-1] (usually frame buffer + ILCP_HEADER_SIZE) and sets
 * *length; X_decode reads a payload of exactly length bytes. HELLO has an empty payload: ilcp_frame_decode
 * with the HELLO bound 0 is all its decoding, ilcp_frame_seal with length 0 its encoding.
 */

/* DESCRIBE flags bit: the bench has no torque sensor (DATA's torque is then ignored: send 0) */
#define ILCP_DESCRIBE_NO_TORQUE_SENSOR 1u

/* DESCRIBE (5.1). backemf_nm_per_a: counts_per_rev rows of (a, b, c), row-major. */
typedef struct {
    uint32_t pole_pairs;
    uint32_t slots;
    uint32_t counts_per_rev;
    uint32_t flags;           /* ILCP_DESCRIBE_NO_TORQUE_SENSOR or 0 */
    double inertia_kgm2;
    double current_scale[3];  /* counts / A, > 0 */
    double current_offset[3]; /* counts */
    double torque_gain;       /* V / N m, > 0 */
    double max_current_a;     /* > 0 */
    double max_torque_nm;     /* > 0 */
    double max_speed_hz;      /* > 0 */
    const double *backemf_nm_per_a;
} ilcp_describe;

/* Both check what a client refuses (5.1): flags beyond ILCP_DESCRIBE_NO_TORQUE_SENSOR (E_FLAGS), motor data
 * out of range (E_RANGE), scales, gain and limits not
 * positive (E_RANGE) and finite, offsets or back-EMF not finite (E_NOT_FINITE). decode copies the back-EMF
 * table into backemf_nm_per_a (capacity backemf_cap doubles, at least 3 counts_per_rev) and points
 * out->backemf_nm_per_a at it. */
ilcp_status ilcp_describe_encode(const ilcp_describe *describe, uint8_t *payload, size_t cap, uint32_t *length);
ilcp_status ilcp_describe_decode(const uint8_t *payload, size_t length, ilcp_describe *out,
                                 double *backemf_nm_per_a, size_t backemf_cap);

/* REQUEST (5.2). feedforward_nm and excitation_nm: table_length values each. */
typedef struct {
    uint32_t trial_id;
    uint32_t revolutions;
    uint32_t seed;
    uint32_t table_length;
    double torque_setpoint_nm;
    double speed_setpoint_hz;
    double current_scale[3];
    double current_offset[3];
    double torque_gain;
    const double *feedforward_nm;
    const double *excitation_nm;
} ilcp_request;

/* encode checks the request as decode does (but not its table_length: only the target knows its N). */
ilcp_status ilcp_request_encode(const ilcp_request *request, uint8_t *payload, size_t cap, uint32_t *length);

/* The REQUEST a target of counts_per_rev counts received, with the checks of section 6 a single frame
 * allows, in its order: size (E_SIZE: answer MALFORMED_FRAME), table_length = counts_per_rev
 * (E_TABLE_LENGTH), tables finite, current_scale and torque_gain positive and finite, current_offset
 * finite, revolutions >= 1, torque_setpoint finite, speed_setpoint positive and finite (E_NOT_FINITE,
 * E_RANGE; all answered BAD_REQUEST). The tables are copied into feedforward_nm and excitation_nm
 * (counts_per_rev doubles each). out->trial_id and the other head fields are set whenever length >= 88,
 * so that a refusal can name the trial. The limits of section 6 (LIMIT_EXCEEDED: speed, torque and
 * current references against the bench's limits) remain the caller's. */
ilcp_status ilcp_request_decode(const uint8_t *payload, size_t length, uint32_t counts_per_rev, ilcp_request *out,
                                double *feedforward_nm, double *excitation_nm);

/* ACCEPT (5.3) */
typedef struct {
    uint32_t trial_id;
    uint64_t max_samples;
} ilcp_accept;

ilcp_status ilcp_accept_encode(const ilcp_accept *accept, uint8_t *payload, size_t cap, uint32_t *length);
ilcp_status ilcp_accept_decode(const uint8_t *payload, size_t length, ilcp_accept *out);

/* DATA (5.4): n samples; the arrays of the columns flags does not name are not read. */
typedef struct {
    uint32_t trial_id;
    uint32_t flags;
    uint64_t first_sample;
    uint32_t n;
    const int64_t *count;            /* n */
    const double *time_s;            /* n */
    const double *i_ref_a;           /* n x 3: sample j, phase p at [3 j + p] */
    const double *torque_nm;         /* n */
    const double *i_meas_a;          /* n x 3, ILCP_COL_I_MEAS */
    const double *torque_true_nm;    /* n, ILCP_COL_TORQUE_TRUE */
    const double *i_true_a;          /* n x 3, ILCP_COL_I_TRUE */
    const double *speed_true_rad_s;  /* n, ILCP_COL_SPEED_TRUE */
} ilcp_data;

/* A decoded DATA payload: each column points into the payload, NULL when absent; sample j (phase p) of a
 * column of width w is ilcp_get_f64(column + 8 (w j + p)), of count ilcp_get_i64(count + 8 j). */
typedef struct {
    uint32_t trial_id;
    uint32_t flags;
    uint64_t first_sample;
    uint32_t n;
    const uint8_t *count;
    const uint8_t *time_s;
    const uint8_t *i_ref_a;
    const uint8_t *torque_nm;
    const uint8_t *i_meas_a;
    const uint8_t *torque_true_nm;
    const uint8_t *i_true_a;
    const uint8_t *speed_true_rad_s;
} ilcp_data_view;

/* W, the values per sample of the columns flags names (6 to 14); 0 if flags has unknown bits. */
uint32_t ilcp_data_width(uint32_t flags);

/* Both refuse unknown flags (E_FLAGS) and n = 0 (E_RANGE); decode checks the size 24 + 8 n W (E_SIZE).
 * What the samples hold, and how frames follow each other in a trial (first_sample, flags, trial_id, the
 * bounds of 5.4, END_OF_TRIAL of 5.6), the receiver checks across frames. */
ilcp_status ilcp_data_encode(const ilcp_data *data, uint8_t *payload, size_t cap, uint32_t *length);
ilcp_status ilcp_data_decode(const uint8_t *payload, size_t length, ilcp_data_view *out);

/* HEARTBEAT (5.5) */
ilcp_status ilcp_heartbeat_encode(uint32_t trial_id, uint8_t *payload, size_t cap, uint32_t *length);
ilcp_status ilcp_heartbeat_decode(const uint8_t *payload, size_t length, uint32_t *trial_id);

/* END_OF_TRIAL (5.6); trial_crc: ilcp_crc32_update over the trial's DATA payloads in order, from 0. */
typedef struct {
    uint32_t trial_id;
    uint32_t data_frames;
    uint64_t n_samples;
    uint32_t trial_crc;
} ilcp_end_of_trial;

ilcp_status ilcp_end_of_trial_encode(const ilcp_end_of_trial *end, uint8_t *payload, size_t cap,
                                     uint32_t *length);
ilcp_status ilcp_end_of_trial_decode(const uint8_t *payload, size_t length, ilcp_end_of_trial *out);

/* ERROR (5.7): message is UTF-8, message_length bytes, not NUL-terminated. */
typedef struct {
    uint32_t code;
    uint32_t trial_id;
    const uint8_t *message;
    size_t message_length;
} ilcp_error;

/* encode cuts a message beyond ILCP_MAX_ERROR_MESSAGE bytes at the last whole UTF-8 character within them;
 * decode points out->message into the payload (the text is not checked: it is for humans). */
ilcp_status ilcp_error_encode(const ilcp_error *error, uint8_t *payload, size_t cap, uint32_t *length);
ilcp_status ilcp_error_decode(const uint8_t *payload, size_t length, ilcp_error *out);

#ifdef __cplusplus
}
#endif

#endif /* ILCPMAC_PROTOCOL_H */
