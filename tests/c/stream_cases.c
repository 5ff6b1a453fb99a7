/* stream_cases.c: the C client's socket layer (examples/c/envlight_client.h) on a stream
 * that tests/c_client.rs serves over TCP in pieces of random size.
 *
 * usage: stream_cases HOST:PORT next|poll
 * Connects (envlight_connect sends the subscribe), then reads frames until the stream ends:
 * `next` with envlight_next, `poll` with envlight_poll in a loop that sleeps 1 ms when no frame
 * is there. stdout: one canonical.h line per frame, then "end CODE" (0 after a goodbye) and,
 * after a goodbye, its text as "goodbye TEXTHEX".
 */
#define _POSIX_C_SOURCE 200112L
#define ENVLIGHT_CLIENT_IMPLEMENTATION
#include "../../examples/c/envlight_client.h"
#include "canonical.h"

#include <stdio.h>
#include <string.h>
#include <time.h>

int main(int argc, char **argv) {
    if (argc != 3) return 2;
    int poll_mode = strcmp(argv[2], "poll") == 0;
    char err[512];
    envlight_client *c = envlight_connect(argv[1], 0, ENVLIGHT_LIGHTS, err, sizeof err);
    if (c == NULL) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    envlight_set_timeout(c, 30000);
    for (;;) {
        const envlight_message *m = NULL;
        int got = poll_mode ? envlight_poll(c, &m) : envlight_next(c, &m);
        if (got == ENVLIGHT_NO_FRAME && poll_mode) {
            struct timespec pause = {0, 1000000L};
            nanosleep(&pause, NULL);
            continue;
        }
        if (got != 1) break;
        print_canonical(m);
    }
    printf("end %d\n", envlight_error_code(c));
    if (envlight_error_code(c) == 0) {
        printf("goodbye");
        canonical_hex(envlight_error(c), strlen(envlight_error(c)));
        printf("\n");
    }
    fprintf(stderr, "%s\n", envlight_error(c));
    envlight_close(c);
    return 0;
}
