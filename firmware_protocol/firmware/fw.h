/*
 * fw.h - reference firmware of the gonio rig controller (../SPEC.md, normative), portable C99.
 *
 * The firmware is one struct (fw_t) and three entry points: fw_rx_byte() for every received byte,
 * fw_poll() as often as possible from the main loop (soft start, watchdog, E-stop, over-temperature), fw_estop_event()
 * from the E-stop pin-change interrupt. All hardware goes through hal.h.
 */
#ifndef FW_FW_H
#define FW_FW_H

#include "../c/fp_codec.h"
#include "hal.h"

#define FW_VERSION 0x0202u /* 0xMMmm: 2.2 */

/* Over-temperature hysteresis: OVERTEMP sets above cfg.overtemp_centi and clears below it minus this. */
#define FW_OVERTEMP_HYSTERESIS_CENTI 500
/* Temperature checked at most this often by fw_poll (an ADC conversion each time), ms. */
#define FW_TEMP_PERIOD_MS 10u


typedef struct {
    uint16_t capabilities;     /* HELLO_REPLY capabilities (FP_CAP_*) */
    uint8_t major;             /* protocol major version served (FP_PROTOCOL_MAJOR) */
    uint8_t minor;             /* protocol minor version served (FP_PROTOCOL_MINOR; lower to act as an older controller) */
    uint16_t pd_full_counts;   /* photodiode ADC counts at full level, warmed up (calibration) */
    uint32_t pd_noise_e6;      /* calibrated single-sample noise, 1e-6 relative (sem for n = 1) */
    uint16_t soft_start_ms;    /* light ramp time from off to the set level (0: instant) */
    int16_t overtemp_centi;    /* the light is cut and SET_LIGHT on refused above this temperature, 0.01 degC */
} fw_config;

typedef struct {
    fw_hal *hal;
    fw_config cfg;
    fp_decoder dec;
    uint8_t configured, light_on, tripped;
    uint8_t overtemp;          /* latched: above the limit, until below the limit minus the hysteresis */
    uint8_t reset_cause;       /* FP_RESET_*: why the controller last reset (set by the HAL at boot) */
    uint32_t temp_checked_ms;  /* when fw_poll last read the temperature */
    uint8_t session_minor;     /* min(host minor from HELLO, cfg.minor): which fields replies carry */
    uint16_t level;            /* level set by the host */
    uint16_t applied;          /* PWM duty now (ramps to level during soft start) */
    uint32_t boot_ms, on_since_ms, last_rx_ms, watchdog_ms;
    uint32_t trigger_count;
    uint32_t pd_time_ms;       /* uptime at the middle of the last photodiode reading (first to last conversion) */
    uint32_t pd_span_us;       /* first to last conversion of the last photodiode reading */
    uint8_t cache_valid, cache_reply_len;
    fp_frame cache_req;        /* last executed request (duplicate rule, SPEC.md section 5) */
    uint8_t cache_reply[FP_MAX_WIRE];
    uint16_t executed[8];      /* requests executed, by TYPE 1..7 (duplicates and refusals excluded) */
    uint16_t duplicates;       /* requests answered from the duplicate cache */
    uint16_t rejects[6];       /* rejected segments, indexed by fp_result (FP_REJ_*) */
} fw_t;

void fw_default_config(fw_config *c);
void fw_init(fw_t *fw, fw_hal *hal, const fw_config *cfg, uint8_t reset_cause); /* power-on / reset */
void fw_rx_byte(fw_t *fw, uint8_t b);
void fw_poll(fw_t *fw);
void fw_estop_event(fw_t *fw);
void fw_cut_light(fw_t *fw); /* after a hardware cut by an interrupt: the firmware's state follows */

#endif
