/* decode_cases.c: the C client's decoder (examples/c/envlight_client.h) on a list of byte
 * strings, for tests/c_client.rs, which compares every answer with envlight's own decoder.
 *
 * stdin: cases, each a little-endian u32 byte count and then that many bytes. stdout: one line
 * per case: "err CODE", or the decoded message with every float as its bit pattern in hex:
 *   frame SEQ TIMEBITS REPRESENTATION STALE COUNT, then per record " ID:BITS:BITS..." (lights,
 *   lobes) or " BASIS LEVELS MAP SIDE" and per coefficient " INDEX:BITS:BITS:BITS" (wavelet);
 *   error CODE TEXTHEX; goodbye TEXTHEX; subscribe MAX REPRESENTATION FORMAT.
 */
#define _POSIX_C_SOURCE 200112L
#define ENVLIGHT_CLIENT_IMPLEMENTATION
#include "../../examples/c/envlight_client.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static unsigned long bits(float v) {
    uint32_t b;
    memcpy(&b, &v, sizeof b);
    return (unsigned long)b;
}

static void floats(const float *v, int n) {
    for (int i = 0; i < n; i++) printf(":%08lx", bits(v[i]));
}

static void hex(const char *text, size_t len) {
    printf(" ");
    for (size_t i = 0; i < len; i++) printf("%02x", (unsigned)(unsigned char)text[i]);
}

int main(void) {
    envlight_message m = {0};
    uint8_t *bytes = NULL;
    for (;;) {
        uint8_t head[4];
        if (fread(head, 1, 4, stdin) != 4) break;
        size_t len = (size_t)head[0] | ((size_t)head[1] << 8) | ((size_t)head[2] << 16) |
                     ((size_t)head[3] << 24);
        uint8_t *grown = (uint8_t *)realloc(bytes, len ? len : 1);
        if (grown == NULL) return 3;
        bytes = grown;
        if (fread(bytes, 1, len, stdin) != len) return 3;
        int rc = envlight_decode(bytes, len, &m, NULL, 0);
        if (rc != ENVLIGHT_OK) {
            printf("err %d\n", rc);
            continue;
        }
        switch (m.type) {
        case ENVLIGHT_TYPE_FRAME: {
            uint64_t time_bits;
            memcpy(&time_bits, &m.time, sizeof time_bits);
            printf("frame %llu %016llx %d %d %lu", (unsigned long long)m.seq,
                   (unsigned long long)time_bits, m.representation, m.stale,
                   (unsigned long)m.count);
            if (m.representation == ENVLIGHT_WAVELET)
                printf(" %d %d %d %lu", m.basis, m.levels, m.map, (unsigned long)m.side);
            for (uint32_t i = 0; i < m.count; i++) {
                if (m.representation == ENVLIGHT_LIGHTS) {
                    const envlight_light *l = &m.lights[i];
                    printf(" %lu", (unsigned long)l->id);
                    floats(l->dir, 3);
                    floats(l->rgb, 3);
                    floats(&l->solid_angle, 1);
                } else if (m.representation == ENVLIGHT_ASG) {
                    const envlight_lobe *g = &m.lobes[i];
                    printf(" %lu", (unsigned long)g->id);
                    floats(g->axis, 3);
                    floats(g->tangent, 3);
                    floats(&g->lambda, 1);
                    floats(&g->mu, 1);
                    floats(g->rgb, 3);
                    floats(&g->integral, 1);
                } else {
                    printf(" %lu", (unsigned long)m.coefficients[i].index);
                    floats(m.coefficients[i].rgb, 3);
                }
            }
            printf("\n");
            break;
        }
        case ENVLIGHT_TYPE_ERROR:
            printf("error %d", m.code);
            hex(m.text, m.text_len);
            printf("\n");
            break;
        case ENVLIGHT_TYPE_GOODBYE:
            printf("goodbye");
            hex(m.text, m.text_len);
            printf("\n");
            break;
        default:
            printf("subscribe %lu %d %d\n", (unsigned long)m.max_lights, m.representation,
                   m.format);
            break;
        }
    }
    envlight_message_free(&m);
    free(bytes);
    return 0;
}
