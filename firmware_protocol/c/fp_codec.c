/* fp_codec.c - see fp_codec.h and ../SPEC.md. C99, no dynamic memory. */
#include "fp_codec.h"

uint32_t fp_crc32c(const uint8_t *data, size_t n)
{
    /* CRC-32C, bitwise, reflected (a 1 KiB table is an option where flash allows). */
    uint32_t crc = 0xFFFFFFFFul;
    size_t i;
    int b;
    for (i = 0; i < n; ++i) {
        crc ^= data[i];
        for (b = 0; b < 8; ++b) {
            crc = (crc & 1u) ? (crc >> 1) ^ 0x82F63B78ul : crc >> 1;
        }
    }
    return crc ^ 0xFFFFFFFFul;
}

static void put_check(uint8_t *k, uint32_t crc)
{
    unsigned i;
    for (i = 0; i < FP_CHECK_SIZE; ++i) {
        k[i] = (uint8_t)(0x80u | ((crc >> (7u * i)) & 0x7Fu));
    }
}

/* 1 and the CRC in *crc if k holds a valid check encoding, else 0. */
static int get_check(const uint8_t *k, uint32_t *crc)
{
    unsigned i;
    uint32_t v = 0;
    for (i = 0; i < FP_CHECK_SIZE; ++i) {
        if (k[i] < 0x80u) {
            return 0;
        }
        v |= (uint32_t)(k[i] & 0x7Fu) << (7u * i);
    }
    if (k[FP_CHECK_SIZE - 1u] & 0x70u) {
        return 0;
    }
    *crc = v;
    return 1;
}

void fp_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

void fp_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

uint16_t fp_get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
}

uint32_t fp_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

size_t fp_encode(const fp_frame *f, uint8_t *out, size_t cap)
{
    uint8_t body[FP_MAX_FRAME];
    size_t n, i, o, code_at;
    uint8_t code;

    if (f->len > FP_MAX_PAYLOAD || cap < (size_t)f->len + FP_MIN_FRAME + 1u + FP_CHECK_SIZE + 2u) {
        return 0;
    }
    body[0] = f->type;
    body[1] = f->seq;
    body[2] = f->len;
    for (i = 0; i < f->len; ++i) {
        body[3 + i] = f->payload[i];
    }
    n = 3u + f->len;

    /* 00 | COBS(body) | check | 00 ; blocks never reach 254 bytes since n <= 67 */
    o = 0;
    out[o++] = 0x00u;
    code_at = o++;
    code = 1u;
    for (i = 0; i < n; ++i) {
        if (body[i] == 0u) {
            out[code_at] = code;
            code_at = o++;
            code = 1u;
        } else {
            out[o++] = body[i];
            ++code;
        }
    }
    out[code_at] = code;
    put_check(&out[o], fp_crc32c(&out[1], o - 1u)); /* the CRC of the encoded bytes */
    o += FP_CHECK_SIZE;
    out[o++] = 0x00u;
    return o;
}

fp_result fp_decode_segment(const uint8_t *seg, size_t n, fp_frame *out)
{
    uint8_t body[FP_MAX_FRAME];
    size_t i = 0, m = 0, j, k;
    uint8_t code;
    uint32_t crc;

    if (n > FP_MAX_ENCODED) {
        return FP_REJ_OVERFLOW;
    }
    if (n < FP_CHECK_SIZE + 1u || !get_check(&seg[n - FP_CHECK_SIZE], &crc) ||
        crc != fp_crc32c(seg, n - FP_CHECK_SIZE)) {
        return FP_REJ_CRC;
    }
    n -= FP_CHECK_SIZE; /* the COBS bytes */
    while (i < n) {
        code = seg[i];
        j = i + code;
        if (code == 0u || j > n) {
            return FP_REJ_COBS;
        }
        for (k = i + 1u; k < j; ++k) {
            if (m >= FP_MAX_FRAME) {
                return FP_REJ_LENGTH;
            }
            body[m++] = seg[k];
        }
        if (code < 0xFFu && j < n) {
            if (m >= FP_MAX_FRAME) {
                return FP_REJ_LENGTH;
            }
            body[m++] = 0u;
        }
        i = j;
    }
    if (m < FP_MIN_FRAME) {
        return FP_REJ_LENGTH;
    }
    if ((size_t)body[2] != m - FP_MIN_FRAME) {
        return FP_REJ_LENGTH;
    }
    out->type = body[0];
    out->seq = body[1];
    out->len = body[2];
    for (k = 0; k < out->len; ++k) {
        out->payload[k] = body[3u + k];
    }
    return FP_OK;
}

void fp_decoder_init(fp_decoder *d)
{
    d->n = 0;
    d->overflow = 0;
}

fp_result fp_decoder_feed(fp_decoder *d, uint8_t byte, fp_frame *out)
{
    fp_result r;
    if (byte != 0u) {
        if (d->overflow || d->n >= FP_MAX_ENCODED) {
            d->overflow = 1;
            d->n = 0;
        } else {
            d->buf[d->n++] = byte;
        }
        return FP_NONE;
    }
    if (d->overflow) {
        d->overflow = 0;
        d->n = 0;
        return FP_REJ_OVERFLOW;
    }
    if (d->n == 0u) {
        return FP_NONE; /* empty segment: repeated delimiter */
    }
    r = fp_decode_segment(d->buf, d->n, out);
    d->n = 0;
    return r;
}
