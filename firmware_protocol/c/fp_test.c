/*
 * fp_test.c - host test program of the C codec (built and run by tests/protocol/test_c_codec.py).
 *
 *   fp_test vectors FILE      check every line of FILE (a line format converted from vectors.json):
 *       C <datahex|-> <crc32c-decimal>
 *       E <type> <seq> <payloadhex|-> <wirehex>
 *       S <wirehex> <nevents> <event>...    event = F:<type>:<seq>:<payloadhex|-> | R:<verdict>
 *   fp_test fuzz SEED N       N seeded random cases (valid frames mutated by bit flips, inserted,
 *                             deleted and random bytes, arbitrary noise); checks that the decoder never
 *                             accepts an inconsistent frame, that a frame with 1..5 flipped bits is never
 *                             accepted, and that the next valid frame is always decoded (resync).
 *   fp_test bench N           decode N frames (benchmarks/bench_protocol.py), print frames, bytes, seconds.
 * Prints "PASS <n>" and exits 0, or prints each failure and exits 1.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fp_codec.h"

#define LINE_MAX_LEN 8192

static int failures = 0;

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* parse hex (or "-" for empty) into out; returns length or -1 */
static long parse_hex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0;
    if (strcmp(s, "-") == 0) return 0;
    while (s[0] && s[1]) {
        int hi = hexval(s[0]), lo = hexval(s[1]);
        if (hi < 0 || lo < 0 || n >= cap) return -1;
        out[n++] = (uint8_t)(hi * 16 + lo);
        s += 2;
    }
    return s[0] ? -1 : (long)n;
}

static const char *verdict_name(fp_result r)
{
    switch (r) {
    case FP_REJ_OVERFLOW: return "overflow";
    case FP_REJ_COBS: return "cobs";
    case FP_REJ_LENGTH: return "length";
    case FP_REJ_CRC: return "crc";
    default: return "?";
    }
}

static void format_event(fp_result r, const fp_frame *f, char *buf, size_t cap)
{
    if (r == FP_OK) {
        size_t o, k;
        o = (size_t)snprintf(buf, cap, "F:%u:%u:", (unsigned)f->type, (unsigned)f->seq);
        if (f->len == 0) {
            snprintf(buf + o, cap - o, "-");
        }
        for (k = 0; k < f->len && o + 3 < cap; ++k) {
            o += (size_t)snprintf(buf + o, cap - o, "%02x", f->payload[k]);
        }
    } else {
        snprintf(buf, cap, "R:%s", verdict_name(r));
    }
}

static void fail(int lineno, const char *what, const char *got, const char *want)
{
    ++failures;
    printf("FAIL line %d: %s: got %s, want %s\n", lineno, what, got, want);
}

static int run_vectors(const char *path)
{
    static char line[LINE_MAX_LEN];
    static uint8_t data[LINE_MAX_LEN / 2], out[FP_MAX_WIRE + 8];
    FILE *fp = fopen(path, "r");
    int lineno = 0, checked = 0;
    if (!fp) {
        printf("FAIL cannot open %s\n", path);
        return 1;
    }
    while (fgets(line, sizeof line, fp)) {
        char *tok[200];
        int nt = 0;
        char *p = strtok(line, " \r\n");
        ++lineno;
        while (p && nt < 200) {
            tok[nt++] = p;
            p = strtok(NULL, " \r\n");
        }
        if (nt == 0) continue;
        if (tok[0][0] == 'C' && nt == 3) {
            long n = parse_hex(tok[1], data, sizeof data);
            unsigned long got = (unsigned long)fp_crc32c(data, (size_t)(n < 0 ? 0 : n)),
                          want = strtoul(tok[2], NULL, 10);
            if (n < 0 || got != want) {
                char g[16], w[16];
                sprintf(g, "%lu", got);
                sprintf(w, "%lu", want);
                fail(lineno, "crc", g, w);
            }
        } else if (tok[0][0] == 'E' && nt == 5) {
            fp_frame f;
            long n = parse_hex(tok[3], f.payload, sizeof f.payload);
            long wn;
            size_t got;
            static uint8_t want[FP_MAX_WIRE + 8];
            f.type = (uint8_t)atoi(tok[1]);
            f.seq = (uint8_t)atoi(tok[2]);
            f.len = (uint8_t)(n < 0 ? 0 : n);
            wn = parse_hex(tok[4], want, sizeof want);
            got = fp_encode(&f, out, sizeof out);
            if (n < 0 || wn < 0 || got != (size_t)wn || memcmp(out, want, got) != 0) {
                fail(lineno, "encode", "different bytes", tok[4]);
            }
        } else if (tok[0][0] == 'S' && nt >= 3) {
            long n = parse_hex(tok[1], data, sizeof data);
            int want_n = atoi(tok[2]), got_n = 0;
            fp_decoder d;
            fp_frame f;
            long i;
            char ev[256];
            fp_decoder_init(&d);
            if (n < 0 || nt != 3 + want_n) {
                fail(lineno, "stream line", "malformed", "well-formed");
                continue;
            }
            for (i = 0; i < n; ++i) {
                fp_result r = fp_decoder_feed(&d, data[i], &f);
                if (r == FP_NONE) continue;
                format_event(r, &f, ev, sizeof ev);
                if (got_n >= want_n) {
                    fail(lineno, "extra event", ev, "none");
                } else if (strcmp(ev, tok[3 + got_n]) != 0) {
                    fail(lineno, "event", ev, tok[3 + got_n]);
                }
                ++got_n;
            }
            if (got_n < want_n) fail(lineno, "missing event", "none", tok[3 + got_n]);
        } else {
            fail(lineno, "line", tok[0], "C, E or S");
            continue;
        }
        ++checked;
    }
    fclose(fp);
    if (failures) return 1;
    printf("PASS %d\n", checked);
    return 0;
}

/* xorshift64* : a tiny seeded generator (Vigna 2016) */
static uint64_t rng_state;
static uint32_t rnd(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (uint32_t)((rng_state * 2685821657736338717ULL) >> 32);
}

static int frames_equal(const fp_frame *a, const fp_frame *b)
{
    return a->type == b->type && a->seq == b->seq && a->len == b->len && memcmp(a->payload, b->payload, a->len) == 0;
}

static int run_fuzz(unsigned long seed, long iterations)
{
    static uint8_t wire[4 * FP_MAX_WIRE + 64], next[FP_MAX_WIRE];
    long it, accepted = 0, undetected = 0, lost_resync = 0;
    rng_state = 0x9E3779B97F4A7C15ULL ^ (uint64_t)seed;
    for (it = 0; it < iterations; ++it) {
        fp_frame orig, sentinel, got;
        fp_decoder d;
        size_t n, nn, i, k;
        int mode = (int)(rnd() % 5u), flips = 0, seen_sentinel = 0;
        orig.type = (uint8_t)rnd();
        orig.seq = (uint8_t)rnd();
        orig.len = (uint8_t)(rnd() % (FP_MAX_PAYLOAD + 1u));
        for (i = 0; i < orig.len; ++i) orig.payload[i] = (uint8_t)(rnd() % 4u == 0u ? 0u : rnd());
        n = fp_encode(&orig, wire, sizeof wire);
        if (mode == 0) {            /* 1..5 bit flips anywhere */
            size_t pos[5];
            flips = 1 + (int)(rnd() % 5u);
            for (k = 0; k < (size_t)flips; ++k) { /* distinct bits: a bit flipped twice is no error */
                size_t q;
                int again;
                do {
                    pos[k] = rnd() % (n * 8u);
                    again = 0;
                    for (q = 0; q < k; ++q) again |= pos[q] == pos[k];
                } while (again);
                wire[pos[k] / 8u] ^= (uint8_t)(1u << (pos[k] % 8u));
            }
        } else if (mode == 1) {     /* delete a byte */
            i = rnd() % n;
            memmove(&wire[i], &wire[i + 1], n - i - 1);
            --n;
        } else if (mode == 2) {     /* insert a random byte */
            i = rnd() % n;
            memmove(&wire[i + 1], &wire[i], n - i);
            wire[i] = (uint8_t)rnd();
            ++n;
        } else if (mode == 3) {     /* pure noise of random length */
            n = rnd() % (sizeof wire - FP_MAX_WIRE);
            for (i = 0; i < n; ++i) wire[i] = (uint8_t)rnd();
        } else {                    /* truncate and append noise */
            n = rnd() % n;
            nn = rnd() % 100u;
            for (i = 0; i < nn; ++i) wire[n++] = (uint8_t)rnd();
        }
        /* a valid sentinel frame after the damage: must always be decoded (resync) */
        sentinel.type = FP_STATUS;
        sentinel.seq = (uint8_t)it;
        sentinel.len = 0;
        nn = fp_encode(&sentinel, next, sizeof next);
        memcpy(&wire[n], next, nn);
        n += nn;
        fp_decoder_init(&d);
        for (i = 0; i < n; ++i) {
            fp_result r = fp_decoder_feed(&d, wire[i], &got);
            if (r != FP_OK) continue;
            if (frames_equal(&got, &sentinel) && i == n - 1) {
                seen_sentinel = 1;
                continue;
            }
            ++accepted;
            {   /* an accepted frame must re-encode to a frame with the same CRC and layout */
                uint8_t re[FP_MAX_WIRE];
                fp_frame back;
                size_t rn = fp_encode(&got, re, sizeof re);
                if (rn < 4 || fp_decode_segment(re + 1, rn - 2, &back) != FP_OK || !frames_equal(&got, &back)) {
                    printf("FAIL fuzz iteration %ld: inconsistent frame accepted\n", it);
                    ++failures;
                }
            }
            if (mode == 0 || (mode != 3 && !frames_equal(&got, &orig))) {
                ++undetected;
                printf("FAIL fuzz iteration %ld: corrupted frame accepted (mode %d)\n", it, mode);
                ++failures;
            }
        }
        if (!seen_sentinel) {
            ++lost_resync;
            printf("FAIL fuzz iteration %ld: no resync on the next valid frame (mode %d)\n", it, mode);
            ++failures;
        }
    }
    printf("fuzz iterations=%ld accepted=%ld undetected=%ld lost_resync=%ld\n", iterations, accepted, undetected,
           lost_resync);
    if (failures) return 1;
    printf("PASS %ld\n", iterations);
    return 0;
}

/* decode n frames (a buffer of 64 mixed frames, fed repeatedly) and report the time */
static int run_bench(long n)
{
    static uint8_t wire[64 * FP_MAX_WIRE];
    size_t len = 0, i;
    long done = 0, k;
    fp_decoder d;
    fp_frame f;
    clock_t t0;
    double secs;
    for (k = 0; k < 64; ++k) {
        fp_frame g;
        g.type = (uint8_t)(0x81 + k % 7);
        g.seq = (uint8_t)k;
        g.len = (uint8_t)(k % 15);
        for (i = 0; i < g.len; ++i) g.payload[i] = (uint8_t)(i * 37u + (size_t)k);
        len += fp_encode(&g, wire + len, sizeof wire - len);
    }
    fp_decoder_init(&d);
    t0 = clock();
    while (done < n) {
        for (i = 0; i < len; ++i) {
            if (fp_decoder_feed(&d, wire[i], &f) == FP_OK) ++done;
        }
    }
    secs = (double)(clock() - t0) / CLOCKS_PER_SEC;
    printf("frames=%ld bytes=%ld seconds=%.6f\n", done, (long)(len * (size_t)(done / 64)), secs);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "bench") == 0) return run_bench(atol(argv[2]));
    if (argc == 3 && strcmp(argv[1], "vectors") == 0) return run_vectors(argv[2]);
    if (argc == 4 && strcmp(argv[1], "fuzz") == 0) return run_fuzz(strtoul(argv[2], NULL, 10), atol(argv[3]));
    fprintf(stderr, "usage: %s vectors FILE | fuzz SEED N | bench N\n", argv[0]);
    return 2;
}
