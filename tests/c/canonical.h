/* canonical.h: one line per decoded message, with every float as its bit pattern in hex, for
 * tests/c_client.rs to compare with envlight's own decoding (its `canonical`):
 *   frame SEQ TIMEBITS REPRESENTATION STALE COUNT, then per record " ID:BITS:BITS..." (lights,
 *   lobes) or " BASIS LEVELS MAP SIDE" and per coefficient " INDEX:BITS:BITS:BITS" (wavelet)
 *   or per coefficient ":BITS:BITS:BITS", with no space, right after COUNT (SH; the degree is
 *   that of COUNT = (degree + 1)^2);
 *   error CODE TEXTHEX; goodbye TEXTHEX; subscribe MAX REPRESENTATION FORMAT.
 * Include after envlight_client.h. */
#include <stdio.h>
#include <string.h>

static unsigned long canonical_bits(float v) {
    uint32_t b;
    memcpy(&b, &v, sizeof b);
    return (unsigned long)b;
}

static void canonical_floats(const float *v, int n) {
    for (int i = 0; i < n; i++) printf(":%08lx", canonical_bits(v[i]));
}

static void canonical_hex(const char *text, size_t len) {
    printf(" ");
    for (size_t i = 0; i < len; i++) printf("%02x", (unsigned)(unsigned char)text[i]);
}

static void print_canonical(const envlight_message *m) {
    switch (m->type) {
    case ENVLIGHT_TYPE_FRAME: {
        uint64_t time_bits;
        memcpy(&time_bits, &m->time, sizeof time_bits);
        printf("frame %llu %016llx %d %d %lu", (unsigned long long)m->seq,
               (unsigned long long)time_bits, m->representation, m->stale,
               (unsigned long)m->count);
        if (m->representation == ENVLIGHT_WAVELET)
            printf(" %d %d %d %lu", m->basis, m->levels, m->map, (unsigned long)m->side);
        for (uint32_t i = 0; i < m->count; i++) {
            if (m->representation == ENVLIGHT_LIGHTS) {
                const envlight_light *l = &m->lights[i];
                printf(" %lu", (unsigned long)l->id);
                canonical_floats(l->dir, 3);
                canonical_floats(l->rgb, 3);
                canonical_floats(&l->solid_angle, 1);
            } else if (m->representation == ENVLIGHT_ASG) {
                const envlight_lobe *g = &m->lobes[i];
                printf(" %lu", (unsigned long)g->id);
                canonical_floats(g->axis, 3);
                canonical_floats(g->tangent, 3);
                canonical_floats(&g->lambda, 1);
                canonical_floats(&g->mu, 1);
                canonical_floats(g->rgb, 3);
                canonical_floats(&g->integral, 1);
            } else if (m->representation == ENVLIGHT_SH) {
                canonical_floats(m->sh[i].rgb, 3);
            } else {
                printf(" %lu", (unsigned long)m->coefficients[i].index);
                canonical_floats(m->coefficients[i].rgb, 3);
            }
        }
        printf("\n");
        break;
    }
    case ENVLIGHT_TYPE_ERROR:
        printf("error %d", m->code);
        canonical_hex(m->text, m->text_len);
        printf("\n");
        break;
    case ENVLIGHT_TYPE_GOODBYE:
        printf("goodbye");
        canonical_hex(m->text, m->text_len);
        printf("\n");
        break;
    default:
        printf("subscribe %lu %d %d\n", (unsigned long)m->max_lights, m->representation,
               m->format);
        break;
    }
}
