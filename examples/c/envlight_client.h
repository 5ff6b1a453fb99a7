/* envlight_client.h: a C client of the envlight wire protocol, version 1 (docs/protocol.md).
 *
 * One header, C99, POSIX sockets, no other dependency; usable from C++ (and from C#, Python or
 * Lua through their C interfaces). Two layers:
 *
 *   - envlight_decode(): one binary message (length prefix included) from a buffer into an
 *     envlight_message, with every check the daemon's own decoder makes (lengths against the
 *     layout of the type and representation, finite floats, valid ASG lobes, wavelet sets and
 *     spherical-harmonic (SH) sets, UTF-8 text). No I/O: use it where the bytes arrive some
 *     other way, e.g. the binary messages of a WebSocket.
 *   - envlight_connect() / envlight_next(): a blocking client over a Unix domain socket or TCP
 *     that subscribes and hands back one frame (light list, ASG set, wavelet set or SH set) per
 *     call; or envlight_poll(), which never waits and hands back the newest frame that has
 *     arrived (for a render loop that wants the current lighting once per frame).
 *
 * In exactly one C or C++ file of a program:
 *
 *     #define ENVLIGHT_CLIENT_IMPLEMENTATION
 *     #include "envlight_client.h"
 *
 * and in the others just the #include. The implementation uses POSIX (getaddrinfo, sockets):
 * with a strict -std=c99, define _POSIX_C_SOURCE=200112L before the first #include (the
 * compilers' default GNU modes need nothing). Example (examples/c/subscribe.c is a complete one):
 *
 *     char err[256];
 *     envlight_client *c = envlight_connect("unix:/run/envlight/envlight.sock", 64,
 *                                           ENVLIGHT_LIGHTS, err, sizeof err);
 *     if (!c) { fprintf(stderr, "%s\n", err); return 1; }
 *     const envlight_message *m;
 *     while (envlight_next(c, &m) == 1)
 *         for (uint32_t i = 0; i < m->count; i++) use(m->lights[i]);
 *     if (envlight_error_code(c) != 0) fprintf(stderr, "%s\n", envlight_error(c));
 *     envlight_close(c);
 *
 * Conventions (DESIGN.md): right-handed, +Y up; a light's `dir` is the unit vector towards it,
 * `rgb` the radiance integrated over its region of the sphere (W/m^2 per channel, so the lights
 * sum to the map's integral and a Lambertian surface with normal n sees
 * E(n) = sum rgb_i max(0, n.dir_i)), `solid_angle` in steradians, `id` stable across frames.
 *
 * The message a call hands back, and the arrays in it, stay valid until the next call on the
 * same client (or envlight_decode() into the same message). No call panics, aborts or reads
 * out of bounds on any input: errors come back as codes with a message.
 *
 * Licence: MIT OR Apache-2.0, as envlight.
 */
#ifndef ENVLIGHT_CLIENT_H
#define ENVLIGHT_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Protocol constants (docs/protocol.md, "Framing"). */
#define ENVLIGHT_PROTOCOL_VERSION 1
#define ENVLIGHT_MAX_MESSAGE_LEN (1u << 20) /* largest length prefix */

/* Message types. */
enum envlight_type {
    ENVLIGHT_TYPE_FRAME = 1,
    ENVLIGHT_TYPE_ERROR = 2,
    ENVLIGHT_TYPE_GOODBYE = 3,
    ENVLIGHT_TYPE_SUBSCRIBE = 16
};

/* What a frame carries. */
enum envlight_representation {
    ENVLIGHT_LIGHTS = 0,  /* directional lights */
    ENVLIGHT_ASG = 1,     /* anisotropic spherical Gaussians (needs [asg] enabled) */
    ENVLIGHT_WAVELET = 2, /* sparse wavelet coefficients (needs [wavelet] enabled) */
    ENVLIGHT_SH = 3       /* spherical-harmonic coefficients (needs [sh] enabled) */
};

/* The highest degree an SH frame may carry in version 1 ((15 + 1)^2 = 256 coefficients). */
#define ENVLIGHT_MAX_SH_DEGREE 15

/* Error codes: those of the protocol's error messages (docs/protocol.md, "Error codes"), which
 * the decoder also returns for bad bytes, plus local ones from 1000 on. 0 is no error (and the
 * goodbye's "shutdown"). */
enum envlight_error_code {
    ENVLIGHT_OK = 0,
    ENVLIGHT_E_MALFORMED = 1,
    ENVLIGHT_E_UNSUPPORTED_VERSION = 2,
    ENVLIGHT_E_UNKNOWN_TYPE = 3,
    ENVLIGHT_E_TOO_LARGE = 4,
    ENVLIGHT_E_BAD_REQUEST = 5,
    ENVLIGHT_E_UNSUPPORTED_REPRESENTATION = 6,
    ENVLIGHT_E_UNEXPECTED_MESSAGE = 7,
    ENVLIGHT_E_INTERNAL = 100,
    ENVLIGHT_E_IO = 1000,        /* connect, read or write failed (errno in the message) */
    ENVLIGHT_E_ADDRESS = 1001,   /* an address that cannot be parsed or resolved */
    ENVLIGHT_E_NO_MEMORY = 1002, /* an allocation failed */
    ENVLIGHT_E_ARGUMENT = 1003   /* a NULL pointer or an invalid argument */
};

/* One directional light: 32 bytes, the layout of the wire record. */
typedef struct envlight_light {
    uint32_t id;       /* index in the progressive point set, stable across frames */
    float dir[3];      /* unit vector towards the light */
    float rgb[3];      /* integrated radiance, W/m^2 */
    float solid_angle; /* steradians */
} envlight_light;

/* One ASG lobe: G(v) = rgb max(v.axis, 0) exp(-lambda (v.tangent)^2 - mu (v.bitangent)^2),
 * bitangent = axis x tangent (docs/asg.md); rgb * integral is its energy in W/m^2. */
typedef struct envlight_lobe {
    uint32_t id;
    float axis[3];
    float tangent[3];
    float lambda;
    float mu;
    float rgb[3];     /* amplitude, W/(m^2 sr) */
    float integral;   /* steradians, > 0 */
} envlight_lobe;

/* One wavelet coefficient: `index` = row * side + column in pywt.coeffs_to_array's layout. */
typedef struct envlight_coefficient {
    uint32_t index;
    float rgb[3];
} envlight_coefficient;

/* One spherical-harmonic coefficient: L_lm = integral of L(w) Y_lm(w) dw per channel, at
 * index l^2 + l + m (-l <= m <= l) of the real orthonormal basis of docs/protocol.md (no
 * Condon-Shortley phase; +Y up, the formulas' polar axis +Z). The radiance towards a unit
 * direction is sum L_lm Y_lm; the integral of L over the sphere is sqrt(4 pi) L_00. */
typedef struct envlight_sh_coefficient {
    float rgb[3];
} envlight_sh_coefficient;

/* A decoded message. Zero-initialise one before its first use (C: envlight_message m = {0};,
 * C++: envlight_message m = {};, or memset) and
 * release it with envlight_message_free() when decoding into it yourself; a client's messages
 * belong to the client. */
typedef struct envlight_message {
    int type; /* enum envlight_type */

    /* ENVLIGHT_TYPE_FRAME */
    uint64_t seq;       /* sequence number of the source frame */
    double time;        /* capture time, seconds since the source started */
    int representation; /* enum envlight_representation */
    int stale;          /* 1: the last known lighting, re-sent while the source is lost */
    uint32_t count;     /* number of records in the one array below that is not NULL */
    const envlight_light *lights;             /* ENVLIGHT_LIGHTS, ordered by id */
    const envlight_lobe *lobes;               /* ENVLIGHT_ASG, ordered by id */
    const envlight_coefficient *coefficients; /* ENVLIGHT_WAVELET, increasing index */
    const envlight_sh_coefficient *sh;        /* ENVLIGHT_SH, (degree + 1)^2 of them */
    int basis;     /* wavelet: 1 = haar, 2..10 = db2..db10, 17..21 = coif1..coif5;
                      SH: 0 = the real orthonormal basis (the only one in version 1) */
    int levels;    /* wavelet: decomposition levels, <= log2(side) */
    int map;       /* wavelet: 0 = equal-area octahedral map */
    uint32_t side; /* wavelet: side of the square map, a power of two */
    int degree;    /* SH: L, 0..ENVLIGHT_MAX_SH_DEGREE; count = (L + 1)^2 */

    /* ENVLIGHT_TYPE_ERROR and ENVLIGHT_TYPE_GOODBYE */
    int code;         /* error code; goodbye: 0 = shutdown */
    const char *text; /* UTF-8, NUL-terminated (the wire text has no NUL of its own length) */
    size_t text_len;  /* bytes of text, without the terminating NUL */

    /* ENVLIGHT_TYPE_SUBSCRIBE (a client's message; a server never sends one) */
    uint32_t max_lights; /* 0 = all */
    int format;          /* 0 = binary, 1 = JSON */

    /* storage of the arrays and text, reused by the next decode into this message */
    void *storage_;
    size_t capacity_;
} envlight_message;

/* Decodes exactly one complete binary message: `len` bytes from `bytes`, length prefix
 * included. Returns ENVLIGHT_OK, or an error code (ENVLIGHT_E_MALFORMED for a message that is
 * cut short or followed by more bytes) with a description in `err` (which may be NULL).
 * Checks everything docs/protocol.md requires, as envlight's own decoder does. */
int envlight_decode(const uint8_t *bytes, size_t len, envlight_message *out, char *err,
                    size_t err_len);

/* Checks the header bytes of a message that has arrived in part: `len` may be anything from
 * 0 up. Returns ENVLIGHT_OK with *message_len = 4 + the length prefix once the prefix has
 * arrived (0 before), or the error code of a header that can be rejected already. */
int envlight_check_header(const uint8_t *bytes, size_t len, size_t *message_len, char *err,
                          size_t err_len);

/* Releases what a message's storage holds; the message can be decoded into again. */
void envlight_message_free(envlight_message *m);

/* The 20 bytes of a binary subscribe: at most max_lights records per frame (0 = all) of
 * `representation`, frames in `format` (0 = binary, 1 = JSON lines). */
void envlight_encode_subscribe(uint32_t max_lights, int representation, int format,
                               uint8_t out[20]);

/* A connection to a daemon. */
typedef struct envlight_client envlight_client;

/* Connects and subscribes for binary frames of `representation`, at most `max_lights` records
 * each (0 = all). `address`: "unix:PATH" or a path containing '/', "tcp:HOST:PORT" or
 * "HOST:PORT" ("[::1]:7878" for IPv6). Returns NULL on failure with the reason in `err`. */
envlight_client *envlight_connect(const char *address, uint32_t max_lights, int representation,
                                  char *err, size_t err_len);

/* Waits for the next frame. Returns 1 with the frame in *frame; 0 when the stream ended
 * cleanly (a goodbye: envlight_error() holds its text, envlight_error_code() is 0); -1 on an
 * error (the daemon's error message, bad bytes, a lost connection: envlight_error_code() and
 * envlight_error() say which). After 0 or -1 every later call returns the same. */
int envlight_next(envlight_client *c, const envlight_message **frame);

/* Does not wait: reads what has arrived and returns 1 with the newest complete frame in
 * *frame (older ones that arrived meanwhile are skipped: compare seq), 2 when no new frame is
 * complete, 0 or -1 as envlight_next() does when the stream has ended (after handing back a
 * frame that came before the end). For a loop that wants the current lighting once per
 * rendered frame without blocking. */
#define ENVLIGHT_NO_FRAME 2
int envlight_poll(envlight_client *c, const envlight_message **frame);

/* Code and text of why the stream ended (ENVLIGHT_OK and the goodbye's text after a goodbye,
 * "" while it runs). */
int envlight_error_code(const envlight_client *c);
const char *envlight_error(const envlight_client *c);

/* The socket, for poll()/select() in an event loop: when it is readable, envlight_poll()
 * takes what arrived (envlight_next() would block until a whole message is there). */
int envlight_fd(const envlight_client *c);

/* Sets a receive timeout (milliseconds, 0 = none): envlight_next() then fails with
 * ENVLIGHT_E_IO when no byte arrives for that long. Returns 0, or -1 with errno set. */
int envlight_set_timeout(envlight_client *c, unsigned milliseconds);

/* Closes the connection and frees the client (NULL is allowed). */
void envlight_close(envlight_client *c);

#ifdef __cplusplus
}
#endif

#endif /* ENVLIGHT_CLIENT_H */

/* ------------------------------------------------------------------------------------------ */
#ifdef ENVLIGHT_CLIENT_IMPLEMENTATION
#ifndef ENVLIGHT_CLIENT_IMPLEMENTED
#define ENVLIGHT_CLIENT_IMPLEMENTED

#include <errno.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/types.h>
#include <sys/un.h>
#include <unistd.h>

#ifdef MSG_NOSIGNAL
#define ENVLIGHT_NOSIGNAL_ MSG_NOSIGNAL /* a closed peer is an error, not SIGPIPE */
#else
#define ENVLIGHT_NOSIGNAL_ 0
#endif
#define ENVLIGHT_HEADER_LEN_ 12u
#define ENVLIGHT_FRAME_FIXED_LEN_ 24u
#define ENVLIGHT_LIGHT_RECORD_ 32u
#define ENVLIGHT_LOBE_RECORD_ 52u
#define ENVLIGHT_WAVELET_PREFIX_ 8u
#define ENVLIGHT_WAVELET_RECORD_ 16u
#define ENVLIGHT_MAX_WAVELET_SIDE_ 32768u
#define ENVLIGHT_SH_PREFIX_ 4u
#define ENVLIGHT_SH_RECORD_ 12u
#define ENVLIGHT_ASG_TOLERANCE_ 1e-3f

static void envlight_say_(char *err, size_t err_len, const char *fmt, ...) {
    if (err == NULL || err_len == 0) return;
    va_list args;
    va_start(args, fmt);
    vsnprintf(err, err_len, fmt, args);
    va_end(args);
}

/* Little-endian reads, whatever the host's byte order. */
static uint16_t envlight_u16_(const uint8_t *b) {
    return (uint16_t)(b[0] | (b[1] << 8));
}
static uint32_t envlight_u32_(const uint8_t *b) {
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) |
           ((uint32_t)b[3] << 24);
}
static uint64_t envlight_u64_(const uint8_t *b) {
    return (uint64_t)envlight_u32_(b) | ((uint64_t)envlight_u32_(b + 4) << 32);
}
static float envlight_f32_(const uint8_t *b) {
    uint32_t bits = envlight_u32_(b);
    float v;
    memcpy(&v, &bits, sizeof v);
    return v;
}
/* A float is finite iff its exponent bits are not all ones. */
static int envlight_finite_bits_(const uint8_t *b) {
    return (envlight_u32_(b) & 0x7f800000u) != 0x7f800000u;
}

void envlight_encode_subscribe(uint32_t max_lights, int representation, int format,
                               uint8_t out[20]) {
    static const uint8_t head[12] = {16, 0, 0, 0, 'E', 'N', 'V', 'L', 1, 0, 16, 0};
    memcpy(out, head, sizeof head);
    out[12] = (uint8_t)max_lights;
    out[13] = (uint8_t)(max_lights >> 8);
    out[14] = (uint8_t)(max_lights >> 16);
    out[15] = (uint8_t)(max_lights >> 24);
    out[16] = (uint8_t)representation;
    out[17] = (uint8_t)format;
    out[18] = 0;
    out[19] = 0;
}

int envlight_check_header(const uint8_t *b, size_t n, size_t *message_len, char *err,
                          size_t err_len) {
    if (message_len) *message_len = 0;
    /* Nothing is judged before the magic has arrived: bytes that are no envlight stream are
       named as such, not as an absurd length, however the first bytes were split. */
    if (n < 8) return ENVLIGHT_OK;
    if (memcmp(b + 4, "ENVL", 4) != 0) {
        envlight_say_(err, err_len,
                      "bad magic %02x %02x %02x %02x (expected \"ENVL\"): not an envlight stream, "
                      "or the stream lost its framing", b[4], b[5], b[6], b[7]);
        return ENVLIGHT_E_MALFORMED;
    }
    uint32_t len = envlight_u32_(b);
    if (len > ENVLIGHT_MAX_MESSAGE_LEN) {
        envlight_say_(err, err_len,
                      "length prefix %lu exceeds the maximum message size of %u bytes",
                      (unsigned long)len, ENVLIGHT_MAX_MESSAGE_LEN);
        return ENVLIGHT_E_TOO_LARGE;
    }
    if (n >= 10 && envlight_u16_(b + 8) != ENVLIGHT_PROTOCOL_VERSION) {
        envlight_say_(err, err_len, "unsupported protocol version %u; this client speaks version 1",
                      envlight_u16_(b + 8));
        return ENVLIGHT_E_UNSUPPORTED_VERSION;
    }
    if (len < 8) {
        envlight_say_(err, err_len, "length prefix %lu is shorter than the 8-byte header after it",
                      (unsigned long)len);
        return ENVLIGHT_E_MALFORMED;
    }
    if (n >= 12) {
        uint16_t type = envlight_u16_(b + 10);
        uint32_t body = len - 8;
        int fits;
        switch (type) {
        case ENVLIGHT_TYPE_FRAME: fits = body >= ENVLIGHT_FRAME_FIXED_LEN_; break;
        case ENVLIGHT_TYPE_ERROR:
        case ENVLIGHT_TYPE_GOODBYE: fits = body >= 6; break;
        case ENVLIGHT_TYPE_SUBSCRIBE: fits = body == 8; break;
        default:
            envlight_say_(err, err_len, "unknown message type %u (version 1 defines 1 = frame, "
                          "2 = error, 3 = goodbye, 16 = subscribe)", type);
            return ENVLIGHT_E_UNKNOWN_TYPE;
        }
        if (!fits) {
            envlight_say_(err, err_len, "length prefix %lu does not fit a message of type %u",
                          (unsigned long)len, type);
            return ENVLIGHT_E_MALFORMED;
        }
    }
    if (message_len) *message_len = 4 + (size_t)len;
    return ENVLIGHT_OK;
}

/* Makes the message's storage hold at least `bytes` (suitably aligned for the records). */
static int envlight_reserve_(envlight_message *m, size_t bytes) {
    if (bytes <= m->capacity_ && m->storage_ != NULL) return 1;
    size_t want = bytes < 256 ? 256 : bytes;
    void *p = realloc(m->storage_, want);
    if (p == NULL) return 0;
    m->storage_ = p;
    m->capacity_ = want;
    return 1;
}

/* Strict UTF-8: no overlong forms, no surrogates, nothing above U+10FFFF. */
static int envlight_utf8_valid_(const uint8_t *s, size_t n) {
    size_t i = 0;
    while (i < n) {
        uint8_t c = s[i];
        if (c < 0x80) { i++; continue; }
        size_t extra;
        uint8_t lo = 0x80, hi = 0xbf; /* allowed range of the second byte */
        if (c >= 0xc2 && c <= 0xdf) extra = 1;
        else if (c == 0xe0) { extra = 2; lo = 0xa0; }
        else if (c >= 0xe1 && c <= 0xec) extra = 2;
        else if (c == 0xed) { extra = 2; hi = 0x9f; }
        else if (c >= 0xee && c <= 0xef) extra = 2;
        else if (c == 0xf0) { extra = 3; lo = 0x90; }
        else if (c >= 0xf1 && c <= 0xf3) extra = 3;
        else if (c == 0xf4) { extra = 3; hi = 0x8f; }
        else return 0;
        if (n - i <= extra) return 0;
        if (s[i + 1] < lo || s[i + 1] > hi) return 0;
        for (size_t k = 2; k <= extra; k++)
            if (s[i + k] < 0x80 || s[i + k] > 0xbf) return 0;
        i += extra + 1;
    }
    return 1;
}

static float envlight_dot_(const float a[3], const float b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* A lobe's bandwidths and integral positive, its frame orthonormal within 1e-3. */
static int envlight_lobe_valid_(const envlight_lobe *g, char *err, size_t err_len, uint32_t i) {
    const float positive[3] = {g->lambda, g->mu, g->integral};
    static const char *const names[3] = {"lambda", "mu", "integral"};
    for (int k = 0; k < 3; k++)
        if (!(positive[k] > 0.0f)) {
            envlight_say_(err, err_len, "ASG lobe %lu is invalid: %s = %g must be positive",
                          (unsigned long)i, names[k], (double)positive[k]);
            return 0;
        }
    const float *vectors[2] = {g->axis, g->tangent};
    static const char *const vector_names[2] = {"axis", "tangent"};
    for (int k = 0; k < 2; k++) {
        float len = sqrtf(envlight_dot_(vectors[k], vectors[k]));
        if (!(fabsf(len - 1.0f) <= ENVLIGHT_ASG_TOLERANCE_)) {
            envlight_say_(err, err_len, "ASG lobe %lu is invalid: %s has length %g, not 1",
                          (unsigned long)i, vector_names[k], (double)len);
            return 0;
        }
    }
    float d = envlight_dot_(g->axis, g->tangent);
    if (!(fabsf(d) <= ENVLIGHT_ASG_TOLERANCE_)) {
        envlight_say_(err, err_len, "ASG lobe %lu is invalid: axis.tangent = %g, not 0",
                      (unsigned long)i, (double)d);
        return 0;
    }
    return 1;
}

/* The records of a frame of `m->count` records after a `prefix` of `rest` bytes: checks that
 * they are exactly `record` bytes each, that the `floats` floats of each record from byte
 * `first` on (after its leading u32 id or index: 4; SH records have none: 0) are finite, and
 * makes room in the message for as many structs of `size` bytes. */
static int envlight_records_(envlight_message *m, const uint8_t *r, size_t rest, size_t prefix,
                             size_t record, size_t first, int floats, size_t size,
                             const char *what, char *err, size_t err_len) {
    uint32_t n = m->count;
    /* n is compared by division first: n * record wraps around a 32-bit size_t. */
    if (rest < prefix || n > (rest - prefix) / record || rest - prefix != (size_t)n * record) {
        envlight_say_(err, err_len, "malformed frame message: count %lu does not fit the %lu "
                      "bytes of records of representation %d", (unsigned long)n,
                      (unsigned long)rest, m->representation);
        return ENVLIGHT_E_MALFORMED;
    }
    r += prefix;
    for (uint32_t i = 0; i < n; i++, r += record)
        for (int k = 0; k < floats; k++)
            if (!envlight_finite_bits_(r + first + 4 * k)) {
                envlight_say_(err, err_len, "non-finite value in %s %lu", what, (unsigned long)i);
                return ENVLIGHT_E_MALFORMED;
            }
    if (!envlight_reserve_(m, (size_t)n * size)) {
        envlight_say_(err, err_len, "out of memory for %lu records", (unsigned long)n);
        return ENVLIGHT_E_NO_MEMORY;
    }
    return ENVLIGHT_OK;
}

/* The frame body after the 24 fixed bytes: `rest` bytes at `r`. */
static int envlight_decode_records_(envlight_message *m, const uint8_t *r, size_t rest,
                                    char *err, size_t err_len) {
    uint32_t n = m->count;
    int rc;
    if (m->representation == ENVLIGHT_LIGHTS) {
        rc = envlight_records_(m, r, rest, 0, ENVLIGHT_LIGHT_RECORD_, 4, 7,
                               sizeof(envlight_light), "light", err, err_len);
        if (rc != ENVLIGHT_OK) return rc;
        envlight_light *lights = (envlight_light *)m->storage_;
        for (uint32_t i = 0; i < n; i++, r += ENVLIGHT_LIGHT_RECORD_) {
            envlight_light *l = &lights[i];
            l->id = envlight_u32_(r);
            for (int k = 0; k < 3; k++) {
                l->dir[k] = envlight_f32_(r + 4 + 4 * k);
                l->rgb[k] = envlight_f32_(r + 16 + 4 * k);
            }
            l->solid_angle = envlight_f32_(r + 28);
        }
        m->lights = lights;
        return ENVLIGHT_OK;
    }
    if (m->representation == ENVLIGHT_ASG) {
        rc = envlight_records_(m, r, rest, 0, ENVLIGHT_LOBE_RECORD_, 4, 12,
                               sizeof(envlight_lobe), "lobe", err, err_len);
        if (rc != ENVLIGHT_OK) return rc;
        envlight_lobe *lobes = (envlight_lobe *)m->storage_;
        for (uint32_t i = 0; i < n; i++, r += ENVLIGHT_LOBE_RECORD_) {
            envlight_lobe *g = &lobes[i];
            g->id = envlight_u32_(r);
            for (int k = 0; k < 3; k++) {
                g->axis[k] = envlight_f32_(r + 4 + 4 * k);
                g->tangent[k] = envlight_f32_(r + 16 + 4 * k);
                g->rgb[k] = envlight_f32_(r + 36 + 4 * k);
            }
            g->lambda = envlight_f32_(r + 28);
            g->mu = envlight_f32_(r + 32);
            g->integral = envlight_f32_(r + 48);
            if (!envlight_lobe_valid_(g, err, err_len, i)) return ENVLIGHT_E_MALFORMED;
        }
        m->lobes = lobes;
        return ENVLIGHT_OK;
    }
    if (m->representation == ENVLIGHT_SH) {
        /* The 4-byte prefix (degree, basis, reserved u16), then 12-byte rgb records. */
        rc = envlight_records_(m, r, rest, ENVLIGHT_SH_PREFIX_, ENVLIGHT_SH_RECORD_, 0, 3,
                               sizeof(envlight_sh_coefficient), "SH coefficient", err, err_len);
        if (rc != ENVLIGHT_OK) return rc;
        m->degree = r[0];
        m->basis = r[1];
        if (m->basis != 0) {
            envlight_say_(err, err_len, "invalid SH set: unknown basis code %d (0 = real "
                          "orthonormal, envlight's axes)", m->basis);
            return ENVLIGHT_E_MALFORMED;
        }
        if (m->degree > ENVLIGHT_MAX_SH_DEGREE) {
            envlight_say_(err, err_len, "invalid SH set: degree %d (at most %d)", m->degree,
                          ENVLIGHT_MAX_SH_DEGREE);
            return ENVLIGHT_E_MALFORMED;
        }
        uint32_t expected = (uint32_t)(m->degree + 1) * (uint32_t)(m->degree + 1);
        if (n != expected) {
            envlight_say_(err, err_len, "invalid SH set: %lu coefficients for degree %d (it has "
                          "%lu)", (unsigned long)n, m->degree, (unsigned long)expected);
            return ENVLIGHT_E_MALFORMED;
        }
        r += ENVLIGHT_SH_PREFIX_;
        envlight_sh_coefficient *sh = (envlight_sh_coefficient *)m->storage_;
        for (uint32_t i = 0; i < n; i++, r += ENVLIGHT_SH_RECORD_)
            for (int k = 0; k < 3; k++) sh[i].rgb[k] = envlight_f32_(r + 4 * k);
        m->sh = sh;
        return ENVLIGHT_OK;
    }
    /* ENVLIGHT_WAVELET: the 8-byte prefix, then 16-byte records */
    rc = envlight_records_(m, r, rest, ENVLIGHT_WAVELET_PREFIX_, ENVLIGHT_WAVELET_RECORD_, 4, 3,
                           sizeof(envlight_coefficient), "coefficient", err, err_len);
    if (rc != ENVLIGHT_OK) return rc;
    m->basis = r[0];
    m->levels = r[1];
    m->map = r[2];
    m->side = envlight_u32_(r + 4);
    if (!(m->basis >= 1 && m->basis <= 10) && !(m->basis >= 17 && m->basis <= 21)) {
        envlight_say_(err, err_len, "invalid wavelet set: unknown basis code %d (1 = haar, "
                      "2..=10 = db2..db10, 17..=21 = coif1..coif5)", m->basis);
        return ENVLIGHT_E_MALFORMED;
    }
    if (m->map != 0) {
        envlight_say_(err, err_len,
                      "invalid wavelet set: unknown map code %d (0 = equal-area octahedral)",
                      m->map);
        return ENVLIGHT_E_MALFORMED;
    }
    uint32_t side = m->side;
    if (side < 2 || side > ENVLIGHT_MAX_WAVELET_SIDE_ || (side & (side - 1)) != 0) {
        envlight_say_(err, err_len, "invalid wavelet set: side %lu is not a power of two in "
                      "2..=32768", (unsigned long)side);
        return ENVLIGHT_E_MALFORMED;
    }
    int max_levels = 0;
    while ((1u << max_levels) < side) max_levels++;
    if (m->levels > max_levels) {
        envlight_say_(err, err_len, "invalid wavelet set: %d levels on side %lu (at most %d)",
                      m->levels, (unsigned long)side, max_levels);
        return ENVLIGHT_E_MALFORMED;
    }
    r += ENVLIGHT_WAVELET_PREFIX_;
    envlight_coefficient *c = (envlight_coefficient *)m->storage_;
    uint64_t cells = (uint64_t)side * side;
    for (uint32_t i = 0; i < n; i++, r += ENVLIGHT_WAVELET_RECORD_) {
        c[i].index = envlight_u32_(r);
        for (int k = 0; k < 3; k++) c[i].rgb[k] = envlight_f32_(r + 4 + 4 * k);
        if (c[i].index >= cells || (i > 0 && c[i].index <= c[i - 1].index)) {
            envlight_say_(err, err_len, "invalid wavelet set: coefficient %lu has index %lu, "
                          "outside 0..side^2 or not above the one before", (unsigned long)i,
                          (unsigned long)c[i].index);
            return ENVLIGHT_E_MALFORMED;
        }
    }
    m->coefficients = c;
    return ENVLIGHT_OK;
}

int envlight_decode(const uint8_t *b, size_t n, envlight_message *m, char *err, size_t err_len) {
    if (err && err_len) err[0] = '\0';
    if (m == NULL || (b == NULL && n > 0)) {
        envlight_say_(err, err_len, "envlight_decode: NULL argument");
        return ENVLIGHT_E_ARGUMENT;
    }
    void *storage = m->storage_;
    size_t capacity = m->capacity_;
    memset(m, 0, sizeof *m);
    m->storage_ = storage;
    m->capacity_ = capacity;
    size_t total = 0;
    int rc = envlight_check_header(b, n, &total, err, err_len);
    if (rc != ENVLIGHT_OK) return rc;
    if (total == 0 || n < total) {
        envlight_say_(err, err_len, "stream ended inside a message (%lu bytes of it received)",
                      (unsigned long)n);
        return ENVLIGHT_E_MALFORMED;
    }
    const uint8_t *body = b + ENVLIGHT_HEADER_LEN_;
    size_t body_len = total - ENVLIGHT_HEADER_LEN_;
    m->type = envlight_u16_(b + 10);
    switch (m->type) {
    case ENVLIGHT_TYPE_FRAME: {
        m->seq = envlight_u64_(body);
        uint64_t time_bits = envlight_u64_(body + 8);
        memcpy(&m->time, &time_bits, sizeof m->time);
        if ((time_bits & 0x7ff0000000000000ull) == 0x7ff0000000000000ull) {
            envlight_say_(err, err_len, "non-finite value in frame time");
            return ENVLIGHT_E_MALFORMED;
        }
        m->representation = body[16];
        if (m->representation > ENVLIGHT_SH) {
            envlight_say_(err, err_len, "unknown representation code %d (0 = lights, 1 = asg, "
                          "2 = wavelet, 3 = sh)", m->representation);
            return ENVLIGHT_E_BAD_REQUEST;
        }
        m->stale = body[17] & 1;
        m->count = envlight_u32_(body + 20);
        rc = envlight_decode_records_(m, body + ENVLIGHT_FRAME_FIXED_LEN_,
                                      body_len - ENVLIGHT_FRAME_FIXED_LEN_, err, err_len);
        break;
    }
    case ENVLIGHT_TYPE_ERROR:
    case ENVLIGHT_TYPE_GOODBYE: {
        m->code = envlight_u16_(body);
        uint32_t text_len = envlight_u32_(body + 2);
        if ((size_t)text_len != body_len - 6) {
            envlight_say_(err, err_len, "malformed %s message: text length %lu, %lu bytes left",
                          m->type == ENVLIGHT_TYPE_ERROR ? "error" : "goodbye",
                          (unsigned long)text_len, (unsigned long)(body_len - 6));
            return ENVLIGHT_E_MALFORMED;
        }
        if (!envlight_utf8_valid_(body + 6, text_len)) {
            envlight_say_(err, err_len, "%s message text is not valid UTF-8",
                          m->type == ENVLIGHT_TYPE_ERROR ? "error" : "goodbye");
            return ENVLIGHT_E_MALFORMED;
        }
        if (!envlight_reserve_(m, (size_t)text_len + 1)) {
            envlight_say_(err, err_len, "out of memory for %lu bytes of text",
                          (unsigned long)text_len);
            return ENVLIGHT_E_NO_MEMORY;
        }
        char *text = (char *)m->storage_;
        memcpy(text, body + 6, text_len);
        text[text_len] = '\0';
        m->text = text;
        m->text_len = text_len;
        break;
    }
    default: /* ENVLIGHT_TYPE_SUBSCRIBE: envlight_check_header() let no other type through */
        m->max_lights = envlight_u32_(body);
        m->representation = body[4];
        m->format = body[5];
        if (m->representation > ENVLIGHT_SH) {
            envlight_say_(err, err_len, "unknown representation code %d", m->representation);
            return ENVLIGHT_E_BAD_REQUEST;
        }
        if (m->format > 1) {
            envlight_say_(err, err_len, "unknown format code %d (0 = binary, 1 = json)", m->format);
            return ENVLIGHT_E_BAD_REQUEST;
        }
        break;
    }
    if (rc != ENVLIGHT_OK) return rc;
    if (n > total) {
        envlight_say_(err, err_len, "%lu bytes after the end of the message",
                      (unsigned long)(n - total));
        return ENVLIGHT_E_MALFORMED;
    }
    return ENVLIGHT_OK;
}

void envlight_message_free(envlight_message *m) {
    if (m == NULL) return;
    free(m->storage_);
    memset(m, 0, sizeof *m);
}

/* ---- the socket client ---- */

struct envlight_client {
    int fd;
    uint8_t *buf;     /* received bytes: [start, end) not yet decoded */
    size_t start, end, capacity;
    envlight_message message;
    envlight_message spare; /* envlight_poll decodes here, then swaps with `message` */
    int state;        /* 1 running, 0 ended with a goodbye, -1 failed */
    int code;
    char error[512];
};

static envlight_client *envlight_fail_connect_(envlight_client *c, char *err, size_t err_len) {
    envlight_say_(err, err_len, "%s", c->error);
    envlight_close(c);
    return NULL;
}

envlight_client *envlight_connect(const char *address, uint32_t max_lights, int representation,
                                  char *err, size_t err_len) {
    if (err && err_len) err[0] = '\0';
    if (address == NULL) {
        envlight_say_(err, err_len, "envlight_connect: NULL address");
        return NULL;
    }
    envlight_client *c = (envlight_client *)calloc(1, sizeof *c);
    if (c == NULL) {
        envlight_say_(err, err_len, "out of memory");
        return NULL;
    }
    c->fd = -1;
    c->state = 1;
    if (representation < ENVLIGHT_LIGHTS || representation > ENVLIGHT_SH) {
        snprintf(c->error, sizeof c->error, "representation %d: expected ENVLIGHT_LIGHTS (0), "
                 "ENVLIGHT_ASG (1), ENVLIGHT_WAVELET (2) or ENVLIGHT_SH (3)", representation);
        return envlight_fail_connect_(c, err, err_len);
    }
    if (strncmp(address, "ws://", 5) == 0 || strncmp(address, "wss://", 6) == 0) {
        snprintf(c->error, sizeof c->error, "%s: this client speaks to the Unix socket and TCP "
                 "endpoints, not WebSocket", address);
        return envlight_fail_connect_(c, err, err_len);
    }
    int is_unix = strncmp(address, "unix:", 5) == 0 ||
                  (strncmp(address, "tcp:", 4) != 0 && strchr(address, '/') != NULL);
    if (is_unix) {
        const char *path = strncmp(address, "unix:", 5) == 0 ? address + 5 : address;
        struct sockaddr_un sa;
        memset(&sa, 0, sizeof sa);
        sa.sun_family = AF_UNIX;
        if (path[0] == '\0' || strlen(path) >= sizeof sa.sun_path) {
            snprintf(c->error, sizeof c->error, "%s: not a usable Unix socket path (empty or "
                     "longer than %u bytes)", address, (unsigned)sizeof sa.sun_path - 1);
            return envlight_fail_connect_(c, err, err_len);
        }
        memcpy(sa.sun_path, path, strlen(path) + 1);
        c->fd = socket(AF_UNIX, SOCK_STREAM, 0);
        if (c->fd < 0 || connect(c->fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
            snprintf(c->error, sizeof c->error, "%s: cannot connect: %s", address,
                     strerror(errno));
            return envlight_fail_connect_(c, err, err_len);
        }
    } else {
        const char *hostport = strncmp(address, "tcp:", 4) == 0 ? address + 4 : address;
        char host[256];
        const char *colon = strrchr(hostport, ':');
        size_t host_len = colon ? (size_t)(colon - hostport) : 0;
        if (colon == NULL || colon[1] == '\0' || host_len == 0 || host_len >= sizeof host) {
            snprintf(c->error, sizeof c->error, "%s: expected unix:PATH, HOST:PORT or "
                     "tcp:HOST:PORT", address);
            c->code = ENVLIGHT_E_ADDRESS;
            return envlight_fail_connect_(c, err, err_len);
        }
        memcpy(host, hostport, host_len);
        host[host_len] = '\0';
        if (host[0] == '[' && host_len >= 2 && host[host_len - 1] == ']') {
            memmove(host, host + 1, host_len - 2);
            host[host_len - 2] = '\0';
        }
        struct addrinfo hints, *found = NULL;
        memset(&hints, 0, sizeof hints);
        hints.ai_family = AF_UNSPEC;
        hints.ai_socktype = SOCK_STREAM;
        int gai = getaddrinfo(host, colon + 1, &hints, &found);
        if (gai != 0) {
            snprintf(c->error, sizeof c->error, "%s: cannot resolve: %s", address,
                     gai_strerror(gai));
            return envlight_fail_connect_(c, err, err_len);
        }
        int last_errno = 0;
        for (struct addrinfo *a = found; a != NULL; a = a->ai_next) {
            c->fd = socket(a->ai_family, a->ai_socktype, a->ai_protocol);
            if (c->fd < 0) { last_errno = errno; continue; }
            if (connect(c->fd, a->ai_addr, a->ai_addrlen) == 0) break;
            last_errno = errno;
            close(c->fd);
            c->fd = -1;
        }
        freeaddrinfo(found);
        if (c->fd < 0) {
            snprintf(c->error, sizeof c->error, "%s: cannot connect: %s", address,
                     strerror(last_errno));
            return envlight_fail_connect_(c, err, err_len);
        }
        int one = 1;
        setsockopt(c->fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    }
    uint8_t subscribe[20];
    envlight_encode_subscribe(max_lights, representation, 0, subscribe);
    size_t sent = 0;
    while (sent < sizeof subscribe) {
        ssize_t w = send(c->fd, subscribe + sent, sizeof subscribe - sent, ENVLIGHT_NOSIGNAL_);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) {
            snprintf(c->error, sizeof c->error, "%s: cannot send the subscribe: %s", address,
                     strerror(errno));
            return envlight_fail_connect_(c, err, err_len);
        }
        sent += (size_t)w;
    }
    c->error[0] = '\0';
    return c;
}

static int envlight_client_fail_(envlight_client *c, int code, const char *fmt, ...) {
    va_list args;
    va_start(args, fmt);
    vsnprintf(c->error, sizeof c->error, fmt, args);
    va_end(args);
    c->code = code;
    c->state = -1;
    return -1;
}

/* The stream ended with `have` bytes of a message unread: a connection closed without a goodbye
 * when there are none, else a message cut short. Fails the client; returns -1. */
static int envlight_stream_ended_(envlight_client *c, size_t have) {
    if (have == 0)
        return envlight_client_fail_(c, ENVLIGHT_E_IO,
                                     "the daemon closed the connection without a goodbye");
    return envlight_client_fail_(c, ENVLIGHT_E_MALFORMED,
                                 "the stream ended inside a message (%lu bytes of it)",
                                 (unsigned long)have);
}

/* Reads more bytes into the buffer, making room for at least `need` bytes from `start`.
 * Returns 1, 0 at the end of the stream, -1 on an error (recorded in c), and without `wait`
 * 2 when no byte is waiting. */
static int envlight_fill_(envlight_client *c, size_t need, int wait) {
    /* The bytes not yet decoded (fewer than `need`) move to the front when the message would
     * not fit behind them or little room is left; the buffer grows only to hold `need` plus
     * a read's worth, so it stays below 1 MiB + 8 KiB or so. */
    if (c->start > 0 && (c->capacity - c->start < need || c->capacity - c->end < 4096)) {
        memmove(c->buf, c->buf + c->start, c->end - c->start);
        c->end -= c->start;
        c->start = 0;
    }
    if (c->capacity < need || c->capacity - c->end < 4096) {
        size_t want = c->capacity < 65536 ? 65536 : c->capacity;
        while (want < need || want - c->end < 4096) want *= 2;
        uint8_t *p = (uint8_t *)realloc(c->buf, want);
        if (p == NULL)
            return envlight_client_fail_(c, ENVLIGHT_E_NO_MEMORY, "out of memory (%lu bytes)",
                                         (unsigned long)want);
        c->buf = p;
        c->capacity = want;
    }
    if (!wait) {
        struct pollfd p;
        p.fd = c->fd;
        p.events = POLLIN;
        p.revents = 0;
        int ready;
        do ready = poll(&p, 1, 0);
        while (ready < 0 && errno == EINTR);
        if (ready == 0) return 2;
        if (ready < 0)
            return envlight_client_fail_(c, ENVLIGHT_E_IO, "poll on the daemon's socket failed: %s",
                                         strerror(errno));
    }
    for (;;) {
        ssize_t r = recv(c->fd, c->buf + c->end, c->capacity - c->end, 0);
        if (r > 0) {
            c->end += (size_t)r;
            return 1;
        }
        if (r == 0) return 0;
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return envlight_client_fail_(c, ENVLIGHT_E_IO, "no data within the receive timeout");
        return envlight_client_fail_(c, ENVLIGHT_E_IO, "reading from the daemon failed: %s",
                                     strerror(errno));
    }
}

int envlight_next(envlight_client *c, const envlight_message **frame) {
    if (frame) *frame = NULL;
    if (c == NULL) return -1;
    if (c->state != 1) return c->state;
    for (;;) {
        size_t have = c->end - c->start, total = 0;
        char why[256];
        int rc = envlight_check_header(c->buf + c->start, have, &total, why, sizeof why);
        if (rc != ENVLIGHT_OK)
            return envlight_client_fail_(c, rc, "bad bytes from the daemon: %s", why);
        if (total == 0 || have < total) {
            /* Wait for the rest of the message (at most 1 MiB + 4 bytes: checked above). */
            size_t need = total > ENVLIGHT_HEADER_LEN_ ? total : ENVLIGHT_HEADER_LEN_;
            int got = envlight_fill_(c, need, 1);
            if (got < 0) return -1;
            if (got == 0) return envlight_stream_ended_(c, have);
            continue;
        }
        rc = envlight_decode(c->buf + c->start, total, &c->message, why, sizeof why);
        c->start += total;
        if (rc != ENVLIGHT_OK)
            return envlight_client_fail_(c, rc, "bad message from the daemon: %s", why);
        switch (c->message.type) {
        case ENVLIGHT_TYPE_FRAME:
            if (frame) *frame = &c->message;
            return 1;
        case ENVLIGHT_TYPE_GOODBYE:
            snprintf(c->error, sizeof c->error, "%s", c->message.text);
            c->code = ENVLIGHT_OK;
            c->state = 0;
            return 0;
        case ENVLIGHT_TYPE_ERROR:
            return envlight_client_fail_(c, c->message.code, "error %d from the daemon: %s",
                                         c->message.code, c->message.text);
        default:
            return envlight_client_fail_(c, ENVLIGHT_E_UNEXPECTED_MESSAGE,
                                         "the daemon sent a message of type %d, which only "
                                         "clients send", c->message.type);
        }
    }
}

int envlight_poll(envlight_client *c, const envlight_message **frame) {
    if (frame) *frame = NULL;
    if (c == NULL) return -1;
    if (c->state != 1) return c->state;
    int have_frame = 0, held_at_end = 0;
    while (!held_at_end) {
        /* Every complete message in the buffer; a frame replaces the one before it. Whatever
         * ends the stream (a goodbye, an error, bad bytes) is left in the buffer while a frame
         * is held: the frame first, the end at the next call. */
        for (;;) {
            size_t have = c->end - c->start, total = 0;
            char why[256];
            int rc = envlight_check_header(c->buf + c->start, have, &total, why, sizeof why);
            if (rc != ENVLIGHT_OK && have_frame) {
                held_at_end = 1;
                break;
            }
            if (rc != ENVLIGHT_OK)
                return envlight_client_fail_(c, rc, "bad bytes from the daemon: %s", why);
            if (total == 0 || have < total) break;
            if (envlight_u16_(c->buf + c->start + 10) != ENVLIGHT_TYPE_FRAME) {
                held_at_end = have_frame;
                if (have_frame) break;
                return envlight_next(c, NULL); /* the goodbye or error: 0 or -1 */
            }
            rc = envlight_decode(c->buf + c->start, total, &c->spare, why, sizeof why);
            if (rc != ENVLIGHT_OK && have_frame) {
                held_at_end = 1;
                break;
            }
            if (rc != ENVLIGHT_OK) {
                c->start += total;
                return envlight_client_fail_(c, rc, "bad message from the daemon: %s", why);
            }
            c->start += total;
            envlight_message newest = c->spare;
            c->spare = c->message;
            c->message = newest;
            have_frame = 1;
        }
        if (held_at_end) break;
        /* Then whatever the socket holds now. */
        size_t have = c->end - c->start, total = 0;
        envlight_check_header(c->buf + c->start, have, &total, NULL, 0);
        size_t need = total > ENVLIGHT_HEADER_LEN_ ? total : ENVLIGHT_HEADER_LEN_;
        int got = envlight_fill_(c, need, 0);
        if (got < 0) return -1;
        if (got == 2) break;
        if (got == 0) {
            if (have_frame) break; /* the end of the stream is reported next time */
            return envlight_stream_ended_(c, have);
        }
    }
    if (!have_frame) return ENVLIGHT_NO_FRAME;
    if (frame) *frame = &c->message;
    return 1;
}

int envlight_error_code(const envlight_client *c) {
    return c ? c->code : ENVLIGHT_E_ARGUMENT;
}

const char *envlight_error(const envlight_client *c) {
    return c ? c->error : "NULL client";
}

int envlight_fd(const envlight_client *c) {
    return c ? c->fd : -1;
}

int envlight_set_timeout(envlight_client *c, unsigned milliseconds) {
    if (c == NULL) {
        errno = EINVAL;
        return -1;
    }
    struct timeval tv;
    tv.tv_sec = (time_t)(milliseconds / 1000);
    tv.tv_usec = (suseconds_t)(milliseconds % 1000) * 1000;
    return setsockopt(c->fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
}

void envlight_close(envlight_client *c) {
    if (c == NULL) return;
    if (c->fd >= 0) close(c->fd);
    free(c->buf);
    envlight_message_free(&c->message);
    envlight_message_free(&c->spare);
    free(c);
}

#endif /* ENVLIGHT_CLIENT_IMPLEMENTED */
#endif /* ENVLIGHT_CLIENT_IMPLEMENTATION */
