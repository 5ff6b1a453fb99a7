/* subscribe.c: a C client of the envlight daemon (envlight_client.h, docs/protocol.md).
 *
 * Connects over a Unix socket or TCP, subscribes, and prints one line per frame: a summary
 * (as examples/client.py does), or with --json the frame in the protocol's JSON form (floats
 * with 9 significant digits, which give back the exact f32; the time with 17).
 *
 *     cc -std=c99 -O2 -o subscribe examples/c/subscribe.c -lm
 *     ./subscribe unix:/run/envlight/envlight.sock
 *     ./subscribe 127.0.0.1:7878 --max-lights 16 --frames 10 --json
 *     ./subscribe 127.0.0.1:7878 --representation asg       # needs [asg] enabled
 *     ./subscribe 127.0.0.1:7878 --representation wavelet   # needs [wavelet] enabled
 *     ./subscribe 127.0.0.1:7878 --representation sh        # needs [sh] enabled
 *     ./subscribe 127.0.0.1:7878 --poll 16   # a 60 Hz render loop that never waits
 *
 * Exit status: 0 after --frames frames or the daemon's goodbye, 1 on an error (the daemon's
 * error message, a lost connection, bad bytes), 2 on a usage error.
 */
#define _POSIX_C_SOURCE 200112L
#define ENVLIGHT_CLIENT_IMPLEMENTATION
#include "envlight_client.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const char usage[] =
    "usage: subscribe ADDRESS [--max-lights N] [--frames N] "
    "[--representation lights|asg|wavelet|sh] [--json] [--poll MS]\n"
    "  ADDRESS: unix:PATH, a socket path, HOST:PORT or tcp:HOST:PORT\n"
    "  --max-lights N   at most N records per frame, the brightest (0 = all; default 0); SH:\n"
    "                   the bands that fit in N coefficients (4 = degrees 0 and 1)\n"
    "  --frames N       stop after N frames (0 = until the daemon's goodbye; default 0)\n"
    "  --representation lights (default), asg (needs [asg] enabled), wavelet ([wavelet])\n"
    "                   or sh ([sh])\n"
    "  --json           print each frame as JSON (docs/protocol.md) instead of a summary\n"
    "  --poll MS        a render loop: every MS milliseconds take the newest frame, if a new\n"
    "                   one came, without waiting (envlight_poll); older ones are skipped\n";

/* A non-negative decimal number that fits in 32 bits, or -1. */
static long parse_count(const char *text) {
    char *end = NULL;
    unsigned long long v = strtoull(text, &end, 10);
    if (text[0] < '0' || text[0] > '9' || end == NULL || *end != '\0' || v > 0xffffffffull)
        return -1;
    return (long)v;
}

static void print_vec(const float v[3]) {
    printf("[%.9g,%.9g,%.9g]", (double)v[0], (double)v[1], (double)v[2]);
}

static const char *basis_name(int code, char *buf, size_t len) {
    if (code == 1) return "haar";
    if (code >= 2 && code <= 10) snprintf(buf, len, "db%d", code);
    else snprintf(buf, len, "coif%d", code - 16);
    return buf;
}

/* The irradiance (W/m^2 per channel) of a surface of unit normal (x, y, z) under an SH set:
 * E(n) = sum_l A_l sum_m L_lm Y_lm(n) (Ramamoorthi & Hanrahan 2001), with A_l the clamped
 * cosine's band factors (pi, 2 pi / 3, pi / 4, 0, -pi / 24, ...; 0 for odd l > 1) and Y_lm
 * the basis of docs/protocol.md: Re, Im of (x + iy)^m times K_l^m P_l^m(z) / sin^m, the last
 * factor by the three-term recurrence in l, as envlight's ShCoefficients::irradiance. */
static void sh_irradiance(const envlight_message *m, double x, double y, double z,
                          double out[3]) {
    const double pi = 3.14159265358979323846;
    double factor[ENVLIGHT_MAX_SH_DEGREE + 1];
    for (int l = 0; l <= m->degree; l++) {
        if (l == 0) factor[l] = pi;
        else if (l == 1) factor[l] = 2.0 * pi / 3.0;
        else if (l % 2 == 1) factor[l] = 0.0;
        else {
            /* 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) * l! / (2^l ((l/2)!)^2) */
            int half = l / 2;
            double central = 1.0;
            for (int k = 1; k <= half; k++) central *= (double)(half + k) / k / 4.0;
            factor[l] = 2.0 * pi * (half % 2 == 1 ? 1.0 : -1.0) * central /
                        ((double)(l + 2) * (l - 1));
        }
    }
    out[0] = out[1] = out[2] = 0.0;
    double re = 1.0, im = 0.0, q_diagonal = 1.0;
    for (int mm = 0; mm <= m->degree; mm++) {
        if (mm > 0) {
            double next_re = re * x - im * y;
            im = re * y + im * x;
            re = next_re;
            q_diagonal *= 2 * mm - 1;
        }
        double q_before = 0.0, q = q_diagonal;
        for (int l = mm; l <= m->degree; l++) {
            if (l > mm) {
                double next = ((2 * l - 1) * z * q - (l + mm - 1) * q_before) / (l - mm);
                q_before = q;
                q = next;
            }
            /* K_l^m = sqrt((2l + 1) / (4 pi) (l - m)! / (l + m)!), times sqrt 2 for m > 0 */
            double ratio = 1.0;
            for (int k = l - mm + 1; k <= l + mm; k++) ratio *= 1.0 / k;
            double norm = sqrt((2 * l + 1) / (4.0 * pi) * ratio) * (mm > 0 ? sqrt(2.0) : 1.0);
            double nq = norm * q;
            for (int k = 0; k < 3; k++) {
                if (mm == 0) {
                    out[k] += factor[l] * m->sh[l * l + l].rgb[k] * nq;
                } else {
                    out[k] += factor[l] * m->sh[l * l + l + mm].rgb[k] * nq * re;
                    out[k] += factor[l] * m->sh[l * l + l - mm].rgb[k] * nq * im;
                }
            }
        }
    }
}

static void print_json(const envlight_message *m) {
    static const char *const names[4] = {"lights", "asg", "wavelet", "sh"};
    printf("{\"seq\":%llu,\"time\":%.17g,\"representation\":\"%s\",\"stale\":%s,",
           (unsigned long long)m->seq, m->time, names[m->representation],
           m->stale ? "true" : "false");
    if (m->representation == ENVLIGHT_LIGHTS) {
        printf("\"lights\":[");
        for (uint32_t i = 0; i < m->count; i++) {
            const envlight_light *l = &m->lights[i];
            printf("%s{\"id\":%lu,\"dir\":", i ? "," : "", (unsigned long)l->id);
            print_vec(l->dir);
            printf(",\"rgb\":");
            print_vec(l->rgb);
            printf(",\"solid_angle\":%.9g}", (double)l->solid_angle);
        }
    } else if (m->representation == ENVLIGHT_ASG) {
        printf("\"lobes\":[");
        for (uint32_t i = 0; i < m->count; i++) {
            const envlight_lobe *g = &m->lobes[i];
            printf("%s{\"id\":%lu,\"axis\":", i ? "," : "", (unsigned long)g->id);
            print_vec(g->axis);
            printf(",\"tangent\":");
            print_vec(g->tangent);
            printf(",\"lambda\":%.9g,\"mu\":%.9g,\"rgb\":", (double)g->lambda, (double)g->mu);
            print_vec(g->rgb);
            printf(",\"integral\":%.9g}", (double)g->integral);
        }
    } else if (m->representation == ENVLIGHT_SH) {
        printf("\"degree\":%d,\"sh\":[", m->degree);
        for (uint32_t i = 0; i < m->count; i++) {
            printf("%s", i ? "," : "");
            print_vec(m->sh[i].rgb);
        }
    } else {
        char buf[16];
        printf("\"basis\":\"%s\",\"side\":%lu,\"levels\":%d,\"coefficients\":[",
               basis_name(m->basis, buf, sizeof buf), (unsigned long)m->side, m->levels);
        for (uint32_t i = 0; i < m->count; i++) {
            printf("%s[%lu,", i ? "," : "", (unsigned long)m->coefficients[i].index);
            print_vec(m->coefficients[i].rgb);
            printf("]");
        }
    }
    printf("]}\n");
}

static void print_summary(const envlight_message *m) {
    double total[3] = {0, 0, 0};
    if (m->representation == ENVLIGHT_SH) {
        /* As `envlight subscribe`: the integral of L over the sphere, sqrt(4 pi) L_00, and the
         * irradiance of a surface facing up (+Y). */
        double up[3];
        sh_irradiance(m, 0.0, 1.0, 0.0, up);
        for (int k = 0; k < 3; k++)
            total[k] = m->sh[0].rgb[k] * sqrt(4.0 * 3.14159265358979323846);
        printf("seq %llu time %.3f s: SH degree %d (%lu coefficients), total rgb [%.4f, %.4f, "
               "%.4f], irradiance up [%.4f, %.4f, %.4f]%s\n", (unsigned long long)m->seq,
               m->time, m->degree, (unsigned long)m->count, total[0], total[1], total[2], up[0],
               up[1], up[2], m->stale ? " (stale)" : "");
        return;
    }
    const char *what = "lights";
    char buf[16];
    char wavelet_what[96];
    for (uint32_t i = 0; i < m->count; i++)
        for (int k = 0; k < 3; k++) {
            if (m->representation == ENVLIGHT_LIGHTS) total[k] += m->lights[i].rgb[k];
            else if (m->representation == ENVLIGHT_ASG)
                total[k] += (double)m->lobes[i].rgb[k] * m->lobes[i].integral;
        }
    if (m->representation == ENVLIGHT_ASG) what = "ASG lobes";
    if (m->representation == ENVLIGHT_WAVELET) {
        /* Sum of texels = 2^levels * sum of the scaling coefficients (the top-left block of
         * side / 2^levels); a texel is 4 pi / side^2 sr. */
        uint32_t block = m->side >> m->levels;
        double scale = (double)(1u << m->levels) * 4.0 * 3.14159265358979323846 /
                       ((double)m->side * m->side);
        for (uint32_t i = 0; i < m->count; i++) {
            uint32_t row = m->coefficients[i].index / m->side;
            uint32_t col = m->coefficients[i].index % m->side;
            if (row < block && col < block)
                for (int k = 0; k < 3; k++) total[k] += scale * m->coefficients[i].rgb[k];
        }
        snprintf(wavelet_what, sizeof wavelet_what, "wavelet coefficients (%s on %lu^2, %d levels)",
                 basis_name(m->basis, buf, sizeof buf), (unsigned long)m->side, m->levels);
        what = wavelet_what;
    }
    printf("seq %llu time %.3f s: %lu %s, total rgb [%.4f, %.4f, %.4f]%s\n",
           (unsigned long long)m->seq, m->time, (unsigned long)m->count, what, total[0],
           total[1], total[2], m->stale ? " (stale)" : "");
}

int main(int argc, char **argv) {
    const char *address = NULL;
    long max_lights = 0, frames = 0, poll_ms = -1;
    int representation = ENVLIGHT_LIGHTS, json = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *value = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--json") == 0) {
            json = 1;
        } else if (strcmp(a, "-h") == 0 || strcmp(a, "--help") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(a, "--max-lights") == 0 || strcmp(a, "--frames") == 0 ||
                   strcmp(a, "--poll") == 0) {
            long v = value ? parse_count(value) : -1;
            if (v < 0) {
                fprintf(stderr, "subscribe: %s needs a count (0..4294967295), got %s\n%s", a,
                        value ? value : "nothing", usage);
                return 2;
            }
            *(a[2] == 'm' ? &max_lights : a[2] == 'f' ? &frames : &poll_ms) = v;
            i++;
        } else if (strcmp(a, "--representation") == 0) {
            if (value && strcmp(value, "lights") == 0) representation = ENVLIGHT_LIGHTS;
            else if (value && strcmp(value, "asg") == 0) representation = ENVLIGHT_ASG;
            else if (value && strcmp(value, "wavelet") == 0) representation = ENVLIGHT_WAVELET;
            else if (value && strcmp(value, "sh") == 0) representation = ENVLIGHT_SH;
            else {
                fprintf(stderr, "subscribe: --representation is lights, asg, wavelet or sh, "
                        "got %s\n", value ? value : "nothing");
                return 2;
            }
            i++;
        } else if (a[0] == '-' || address != NULL) {
            fprintf(stderr, "subscribe: unexpected argument %s\n%s", a, usage);
            return 2;
        } else {
            address = a;
        }
    }
    if (address == NULL) {
        fputs(usage, stderr);
        return 2;
    }

    char err[512];
    envlight_client *c =
        envlight_connect(address, (uint32_t)max_lights, representation, err, sizeof err);
    if (c == NULL) {
        fprintf(stderr, "subscribe: %s\n", err);
        return 1;
    }
    long received = 0;
    const envlight_message *m = NULL;
    int status = 0;
    while (frames == 0 || received < frames) {
        int got;
        if (poll_ms >= 0) {
            /* A render loop's frame: the work of the frame, here a sleep, then the newest
             * lighting if new lighting came. */
            struct timespec pause;
            pause.tv_sec = poll_ms / 1000;
            pause.tv_nsec = (poll_ms % 1000) * 1000000L;
            nanosleep(&pause, NULL);
            got = envlight_poll(c, &m);
            if (got == ENVLIGHT_NO_FRAME) continue;
        } else {
            got = envlight_next(c, &m);
        }
        if (got == 0) {
            fprintf(stderr, "goodbye: %s\n", envlight_error(c));
            break;
        }
        if (got < 0) {
            fprintf(stderr, "subscribe: %s: %s\n", address, envlight_error(c));
            status = 1;
            break;
        }
        if (json) print_json(m);
        else print_summary(m);
        fflush(stdout);
        received++;
    }
    envlight_close(c);
    return status;
}
