/* decode_cases.c: the C client's decoder (examples/c/envlight_client.h) on a list of byte
 * strings, for tests/c_client.rs, which compares every answer with envlight's own decoder.
 *
 * stdin: cases, each a little-endian u32 byte count and then that many bytes. stdout: one line
 * per case: "err CODE", or the decoded message in canonical.h's line format.
 */
#define _POSIX_C_SOURCE 200112L
#define ENVLIGHT_CLIENT_IMPLEMENTATION
#include "../../examples/c/envlight_client.h"
#include "canonical.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int main(void) {
    envlight_message m;
    memset(&m, 0, sizeof m);
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
        if (rc != ENVLIGHT_OK)
            printf("err %d\n", rc);
        else
            print_canonical(&m);
    }
    envlight_message_free(&m);
    free(bytes);
    return 0;
}
