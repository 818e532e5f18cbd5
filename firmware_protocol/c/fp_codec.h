/*
 * fp_codec.h - C99 codec of the gonio rig-controller protocol (see ../SPEC.md, normative).
 *
 * Frame on the wire:  00 | E | K | 00,   E = COBS( TYPE SEQ LEN PAYLOAD[LEN] ),
 *                     K = CRC-32C(E) in five bytes: 0x80 | bits 0-6, 7-13, 14-20, 21-27, 28-31.
 * CRC-32C (Castagnoli, iSCSI): reflected poly 0x82F63B78, init and xorout 0xFFFFFFFF. The check covers
 * the bytes on the wire, so every pattern of up to 5 flipped bits is detected (SPEC.md section 2.5).
 *
 * No malloc, no globals, fixed buffers: a decoder is one struct of ~80 bytes the firmware owns.
 */
#ifndef FP_CODEC_H
#define FP_CODEC_H

#include <stddef.h>
#include <stdint.h>

#define FP_PROTOCOL_MAJOR 2u
#define FP_PROTOCOL_MINOR 2u /* 2.1: READ_PHOTODIODE_REPLY carries time_ms, span_us; 2.2: STATUS_REPLY reset_cause,
                                only TRIGGER answered from the duplicate cache, OVERTEMP cuts the light */

#define FP_MAX_PAYLOAD 64u
#define FP_MIN_FRAME 3u                                /* body: TYPE SEQ LEN */
#define FP_MAX_FRAME (FP_MIN_FRAME + FP_MAX_PAYLOAD)   /* 67 */
#define FP_CHECK_SIZE 5u                               /* CRC-32C in five 7-bit groups */
#define FP_MAX_ENCODED (FP_MAX_FRAME + 1u + FP_CHECK_SIZE) /* 73: COBS adds one byte, then the check */
#define FP_MAX_WIRE (FP_MAX_ENCODED + 2u)              /* 75: with both delimiters */

/* message types (SPEC.md section 4); replies are request | FP_REPLY_BIT */
#define FP_REPLY_BIT 0x80u
#define FP_HELLO 0x01u
#define FP_HEARTBEAT 0x02u
#define FP_SET_LIGHT 0x03u
#define FP_READ_PHOTODIODE 0x04u
#define FP_TRIGGER 0x05u
#define FP_STATUS 0x06u
#define FP_SET_WATCHDOG 0x07u
#define FP_ERROR 0xFFu

/* capability bits (HELLO reply) */
#define FP_CAP_DIMMING 0x0001u
#define FP_CAP_PHOTODIODE 0x0002u
#define FP_CAP_TRIGGER 0x0004u
#define FP_CAP_TEMPERATURE 0x0008u
#define FP_CAP_INTERLOCK 0x0010u

/* status flags (STATUS reply) */
#define FP_FLAG_ESTOP 0x0001u
#define FP_FLAG_INTERLOCK_OPEN 0x0002u
#define FP_FLAG_LIGHT_ON 0x0004u
#define FP_FLAG_WATCHDOG_TRIPPED 0x0008u
#define FP_FLAG_NOT_CONFIGURED 0x0010u
#define FP_FLAG_OVERTEMP 0x0020u
#define FP_FLAG_TRIGGER_ACTIVE 0x0040u

/* reset causes (STATUS reply reset_cause, since 2.2) */
#define FP_RESET_UNKNOWN 0u
#define FP_RESET_POWER_ON 1u
#define FP_RESET_EXTERNAL 2u
#define FP_RESET_BROWN_OUT 3u
#define FP_RESET_WATCHDOG 4u

/* status flags that mean "unsafe": the light is off and stays off; a host stops its session (SPEC 4.2) */
#define FP_UNSAFE_FLAGS (FP_FLAG_ESTOP | FP_FLAG_INTERLOCK_OPEN | FP_FLAG_OVERTEMP | FP_FLAG_WATCHDOG_TRIPPED)

/* error codes (ERROR reply) */
#define FP_ERR_UNKNOWN_TYPE 0x01u
#define FP_ERR_BAD_LENGTH 0x02u
#define FP_ERR_BAD_VALUE 0x03u
#define FP_ERR_ESTOP 0x04u
#define FP_ERR_NOT_READY 0x05u
#define FP_ERR_BUSY 0x06u
#define FP_ERR_VERSION 0x07u
#define FP_ERR_OVERTEMP 0x08u

typedef struct {
    uint8_t type;
    uint8_t seq;
    uint8_t len;
    uint8_t payload[FP_MAX_PAYLOAD];
} fp_frame;

/* Result of feeding one byte to the decoder. */
typedef enum {
    FP_NONE = 0,      /* nothing completed yet */
    FP_OK = 1,        /* *out holds a valid frame */
    FP_REJ_OVERFLOW,  /* segment longer than FP_MAX_ENCODED */
    FP_REJ_COBS,      /* a COBS block overruns the segment */
    FP_REJ_LENGTH,    /* decoded size outside 3..67, or LEN != size - 3 */
    FP_REJ_CRC        /* check bytes malformed or CRC-32C mismatch */
} fp_result;

typedef struct {
    uint8_t buf[FP_MAX_ENCODED];
    size_t n;
    int overflow;
} fp_decoder;

uint32_t fp_crc32c(const uint8_t *data, size_t n);

/* Encode frame f into out (capacity cap); returns bytes written (<= FP_MAX_WIRE) or 0 if f->len is
 * too large or cap too small. */
size_t fp_encode(const fp_frame *f, uint8_t *out, size_t cap);

void fp_decoder_init(fp_decoder *d);

/* Feed one received byte; on FP_OK the frame is written to *out. Never fails on any input. */
fp_result fp_decoder_feed(fp_decoder *d, uint8_t byte, fp_frame *out);

/* Decode one segment (bytes between delimiters, no zero bytes); same verdicts as the stream decoder. */
fp_result fp_decode_segment(const uint8_t *seg, size_t n, fp_frame *out);

/* Little-endian payload helpers. */
void fp_put_u16(uint8_t *p, uint16_t v);
void fp_put_u32(uint8_t *p, uint32_t v);
uint16_t fp_get_u16(const uint8_t *p);
uint32_t fp_get_u32(const uint8_t *p);

#endif /* FP_CODEC_H */
