/*
 * fw.c - reference firmware of the gonio rig controller: the whole of ../SPEC.md (handshake, message
 * catalogue, duplicate rule, watchdog, E-stop, over-temperature cut) over the codec in ../c and the HAL in hal.h.
 * C99, no malloc, no floating point except the photodiode statistics (one reading at a time).
 */
#include "fw.h"

#include <math.h>

#ifdef FW_HOST
int hal_host_brownout(fw_hal *h); /* host build only: fault injection (a reset before the next frame) */
#endif

void fw_default_config(fw_config *c)
{
    c->capabilities = FP_CAP_DIMMING | FP_CAP_PHOTODIODE | FP_CAP_TRIGGER | FP_CAP_TEMPERATURE | FP_CAP_INTERLOCK;
    c->major = FP_PROTOCOL_MAJOR;
    c->minor = FP_PROTOCOL_MINOR;
    c->pd_full_counts = 900u;   /* 10-bit ADC: full level at ~88 % of full scale, headroom for drift */
    c->pd_noise_e6 = 2000u;
    c->soft_start_ms = 50u;
    c->overtemp_centi = 7000;
}

static void light_cut(fw_t *fw)
{
    fw->light_on = 0;
    fw->applied = 0;
    hal_light_set(fw->hal, 0);
}

void fw_init(fw_t *fw, fw_hal *hal, const fw_config *cfg, uint8_t reset_cause)
{
    uint8_t i;
    fw->hal = hal;
    fw->cfg = *cfg;
    fp_decoder_init(&fw->dec);
    fw->configured = 0;
    fw->session_minor = 0;
    fw->tripped = 0;
    fw->overtemp = 0;
    fw->reset_cause = reset_cause;
    fw->level = 0;
    light_cut(fw);
    fw->boot_ms = hal_millis(hal);
    fw->on_since_ms = fw->boot_ms;
    fw->last_rx_ms = fw->boot_ms;
    fw->temp_checked_ms = fw->boot_ms - FW_TEMP_PERIOD_MS; /* the first poll reads the temperature */
    fw->watchdog_ms = 10000ul;
    fw->trigger_count = 0;
    fw->pd_time_ms = 0;
    fw->pd_span_us = 0;
    fw->cache_valid = 0;
    fw->cache_reply_len = 0;
    for (i = 0; i < 8u; ++i) {
        fw->executed[i] = 0;
    }
    for (i = 0; i < 6u; ++i) {
        fw->rejects[i] = 0;
    }
    fw->duplicates = 0;
}

void fw_cut_light(fw_t *fw)
{
    light_cut(fw);
}

/* E-stop loop open or interlock open: cut the light (the hardware loop also cuts the driver's enable).
 * The cut latches: the light stays off after release until the host switches it on again. */
void fw_estop_event(fw_t *fw)
{
    if ((hal_estop_pressed(fw->hal) || hal_interlock_open(fw->hal)) && (fw->light_on || fw->applied)) {
        light_cut(fw);
    }
}

static void check_watchdog(fw_t *fw, uint32_t now)
{
    if (fw->light_on && (uint32_t)(now - fw->last_rx_ms) > fw->watchdog_ms) {
        light_cut(fw);
        fw->tripped = 1;
    }
}

static void soft_start(fw_t *fw, uint32_t now)
{
    uint32_t el, duty;
    if (!fw->light_on || fw->applied == fw->level) {
        return;
    }
    el = now - fw->on_since_ms;
    if (fw->cfg.soft_start_ms == 0u || el >= fw->cfg.soft_start_ms) {
        duty = fw->level;
    } else {
        duty = (uint32_t)fw->level * el / fw->cfg.soft_start_ms; /* linear ramp from switch-on */
    }
    if (duty != fw->applied) {
        fw->applied = (uint16_t)duty;
        hal_light_set(fw->hal, fw->applied);
    }
}

static int16_t temperature(fw_t *fw)
{
    return hal_temperature_centi(fw->hal);
}

/* Over-temperature (SPEC.md section 4.2): OVERTEMP sets when the light source's temperature exceeds the
 * limit and clears only once it is below the limit minus the hysteresis; while it is set the light is cut
 * (and stays off, like after an E-stop, until the host switches it on again) and switch-on is refused. */
static void check_overtemp(fw_t *fw, uint32_t now)
{
    int16_t t = temperature(fw);
    fw->temp_checked_ms = now;
    if (t > fw->cfg.overtemp_centi) {
        fw->overtemp = 1;
    } else if ((int32_t)t < (int32_t)fw->cfg.overtemp_centi - FW_OVERTEMP_HYSTERESIS_CENTI) {
        fw->overtemp = 0;
    }
    if (fw->overtemp && (fw->light_on || fw->applied)) {
        light_cut(fw);
    }
}

void fw_poll(fw_t *fw)
{
    uint32_t now = hal_millis(fw->hal);
    fw_estop_event(fw);
    check_watchdog(fw, now);
    if ((uint32_t)(now - fw->temp_checked_ms) >= FW_TEMP_PERIOD_MS) {
        check_overtemp(fw, now);
    }
    soft_start(fw, now);
}

static uint16_t flags(fw_t *fw, uint32_t now)
{
    uint16_t f = 0;
    (void)now;
    if (hal_estop_pressed(fw->hal)) f |= FP_FLAG_ESTOP;
    if (hal_interlock_open(fw->hal)) f |= FP_FLAG_INTERLOCK_OPEN;
    if (fw->light_on) f |= FP_FLAG_LIGHT_ON;
    if (fw->tripped) f |= FP_FLAG_WATCHDOG_TRIPPED;
    if (!fw->configured) f |= FP_FLAG_NOT_CONFIGURED;
    if (fw->overtemp) f |= FP_FLAG_OVERTEMP;
    if (hal_trigger_active(fw->hal)) f |= FP_FLAG_TRIGGER_ACTIVE;
    return f;
}

/* Photodiode: n conversions; mean and standard uncertainty of the mean, 1e-6 relative.
 * Shifted-data variance (Chan, Golub & LeVeque 1983): s = sum(x - x0), q = sum((x - x0)^2),
 * var = (q - s^2/n) / (n - 1), sem = sqrt(var / n); n = 1 reports the calibrated noise.
 * Timestamp (SPEC.md section 4.4): span = first to last conversion (us timer), time = uptime (ms) at
 * the first conversion + span / 2, rounded: the instant a mean of a linearly drifting signal stands for. */
static void photodiode(fw_t *fw, uint8_t n, uint32_t *mean_e6, uint32_t *sem_e6)
{
    uint32_t t0 = hal_millis(fw->hal), u0 = hal_micros(fw->hal), u1 = u0;
    double x0 = 0.0, s = 0.0, q = 0.0, d, scale = 1e6 / (double)fw->cfg.pd_full_counts, m, v;
    uint8_t i;
    for (i = 0; i < n; ++i) {
        if (i + 1u == n) {
            u1 = hal_micros(fw->hal); /* start of the last conversion (u0: of the first) */
        }
        d = (double)hal_adc_photodiode(fw->hal);
        if (i == 0) {
            x0 = d;
        }
        d -= x0;
        s += d;
        q += d * d;
    }
    fw->pd_span_us = u1 - u0;
    fw->pd_time_ms = t0 - fw->boot_ms + (fw->pd_span_us / 2u + 500u) / 1000u;
    m = (x0 + s / n) * scale;
    *mean_e6 = m <= 0.0 ? 0u : m >= 4294967295.0 ? 0xFFFFFFFFul : (uint32_t)(m + 0.5);
    if (n < 2u) {
        *sem_e6 = fw->cfg.pd_noise_e6;
        return;
    }
    v = (q - s * s / n) / (double)(n - 1u);
    v = v > 0.0 ? sqrt(v / n) * scale : 0.0;
    *sem_e6 = v >= 4294967295.0 ? 0xFFFFFFFFul : (uint32_t)(v + 0.5);
}

/* Reply payload sizes by request type 1..7 (SPEC.md section 4) and request payload sizes. */
static const uint8_t REQ_SIZE[8] = {0, 2, 0, 3, 1, 4, 0, 4};

static uint8_t reply(fw_t *fw, const fp_frame *req, uint8_t type, const uint8_t *p, uint8_t len)
{
    fp_frame r;
    uint8_t i;
    r.type = type;
    r.seq = req->seq;
    r.len = len;
    for (i = 0; i < len; ++i) {
        r.payload[i] = p[i];
    }
    return (uint8_t)fp_encode(&r, fw->cache_reply, sizeof fw->cache_reply);
}

static uint8_t error(fw_t *fw, const fp_frame *req, uint8_t code)
{
    uint8_t p[2];
    p[0] = code;
    p[1] = req->type;
    return reply(fw, req, FP_ERROR, p, 2);
}

/* Execute request f; the encoded reply is left in fw->cache_reply, its length returned. */
static uint8_t execute(fw_t *fw, const fp_frame *f, uint32_t now)
{
    uint8_t p[20];
    const uint8_t *a = f->payload;
    uint32_t u, mean, sem;
    uint16_t lvl;

    if (f->type < FP_HELLO || f->type > FP_SET_WATCHDOG) {
        return error(fw, f, FP_ERR_UNKNOWN_TYPE);
    }
    if (f->len != REQ_SIZE[f->type]) {
        return error(fw, f, FP_ERR_BAD_LENGTH);
    }
    if ((f->type == FP_SET_LIGHT && a[0] > 1u) || (f->type == FP_READ_PHOTODIODE && a[0] == 0u) ||
        (f->type == FP_TRIGGER && (fp_get_u32(a) < 1ul || fp_get_u32(a) > 600000000ul)) ||
        (f->type == FP_SET_WATCHDOG && (fp_get_u32(a) < 100ul || fp_get_u32(a) > 3600000ul))) {
        return error(fw, f, FP_ERR_BAD_VALUE);
    }
    if (!fw->configured && f->type != FP_HELLO && f->type != FP_STATUS) {
        return error(fw, f, FP_ERR_NOT_READY);
    }
    fw->executed[f->type]++;
    switch (f->type) {
    case FP_HELLO:
        if (a[0] != fw->cfg.major) {
            fw->executed[f->type]--;
            return error(fw, f, FP_ERR_VERSION);
        }
        fw->configured = 1;
        fw->session_minor = a[1] < fw->cfg.minor ? a[1] : fw->cfg.minor; /* fields both ends know */
        p[0] = fw->cfg.major;
        p[1] = fw->cfg.minor;
        fp_put_u16(&p[2], fw->cfg.capabilities);
        fp_put_u16(&p[4], FW_VERSION);
        p[6] = FP_MAX_PAYLOAD;
        fp_put_u32(&p[7], fw->watchdog_ms);
        return reply(fw, f, FP_HELLO | FP_REPLY_BIT, p, 11);
    case FP_HEARTBEAT:
        return reply(fw, f, FP_HEARTBEAT | FP_REPLY_BIT, p, 0);
    case FP_SET_LIGHT:
        lvl = fp_get_u16(&a[1]);
        if (a[0]) {
            if (hal_estop_pressed(fw->hal) || hal_interlock_open(fw->hal)) {
                fw->executed[f->type]--;
                return error(fw, f, FP_ERR_ESTOP);
            }
            check_overtemp(fw, now);
            if (fw->overtemp) {
                fw->executed[f->type]--;
                return error(fw, f, FP_ERR_OVERTEMP);
            }
            if (!fw->light_on) {
                fw->on_since_ms = now; /* switch-on restarts warm-up and the soft start */
                fw->applied = 0;
            }
            fw->light_on = 1;
            fw->level = lvl;
            fw->tripped = 0;
            soft_start(fw, now);
        } else {
            light_cut(fw);
        }
        p[0] = fw->light_on;
        fp_put_u16(&p[1], lvl);
        return reply(fw, f, FP_SET_LIGHT | FP_REPLY_BIT, p, 3);
    case FP_READ_PHOTODIODE:
        photodiode(fw, a[0], &mean, &sem);
        p[0] = a[0];
        fp_put_u32(&p[1], mean);
        fp_put_u32(&p[5], sem);
        if (fw->session_minor < 1u) {
            return reply(fw, f, FP_READ_PHOTODIODE | FP_REPLY_BIT, p, 9); /* a 2.0 host: no timestamp */
        }
        fp_put_u32(&p[9], fw->pd_time_ms);
        fp_put_u32(&p[13], fw->pd_span_us);
        return reply(fw, f, FP_READ_PHOTODIODE | FP_REPLY_BIT, p, 17);
    case FP_TRIGGER:
        if (hal_trigger_active(fw->hal)) {
            fw->executed[f->type]--;
            return error(fw, f, FP_ERR_BUSY);
        }
        u = fp_get_u32(a);
        hal_trigger_start(fw->hal, u);
        fw->trigger_count++;
        fp_put_u32(&p[0], u);
        fp_put_u32(&p[4], fw->trigger_count);
        return reply(fw, f, FP_TRIGGER | FP_REPLY_BIT, p, 8);
    case FP_STATUS:
        check_overtemp(fw, now);
        fp_put_u16(&p[0], flags(fw, now));
        fp_put_u16(&p[2], fw->light_on ? fw->level : 0u);
        fp_put_u16(&p[4], (uint16_t)temperature(fw));
        fp_put_u32(&p[6], now - fw->boot_ms);
        fp_put_u32(&p[10], fw->watchdog_ms);
        if (fw->session_minor < 2u) {
            return reply(fw, f, FP_STATUS | FP_REPLY_BIT, p, 14); /* a 2.0/2.1 host: no reset cause */
        }
        p[14] = fw->reset_cause;
        return reply(fw, f, FP_STATUS | FP_REPLY_BIT, p, 15);
    default: /* FP_SET_WATCHDOG */
        fw->watchdog_ms = fp_get_u32(a);
        fp_put_u32(&p[0], fw->watchdog_ms);
        return reply(fw, f, FP_SET_WATCHDOG | FP_REPLY_BIT, p, 4);
    }
}

static int same_request(const fp_frame *x, const fp_frame *y)
{
    uint8_t i;
    if (x->type != y->type || x->seq != y->seq || x->len != y->len) {
        return 0;
    }
    for (i = 0; i < x->len; ++i) {
        if (x->payload[i] != y->payload[i]) {
            return 0;
        }
    }
    return 1;
}

static void handle(fw_t *fw, const fp_frame *f)
{
    uint32_t now;
    uint8_t n, i;
#ifdef FW_HOST
    if (hal_host_brownout(fw->hal)) {
        fw_config c = fw->cfg;
        fw_init(fw, fw->hal, &c, FP_RESET_BROWN_OUT);
    }
#endif
    now = hal_millis(fw->hal);
    fw_estop_event(fw);
    check_watchdog(fw, now);
    fw->last_rx_ms = now; /* every accepted frame feeds the watchdog (SPEC.md section 6) */
    if (f->type & FP_REPLY_BIT) {
        return; /* replies are never answered */
    }
    /* the duplicate rule (SPEC.md section 5): only a non-idempotent request (TRIGGER) is answered from the
     * cache; every other one is executed again, so its reply says what holds now, not what held then */
    if (fw->cache_valid && f->type == FP_TRIGGER && same_request(f, &fw->cache_req)) {
        fw->duplicates++;
        hal_uart_write(fw->hal, fw->cache_reply, fw->cache_reply_len);
        return;
    }
    n = execute(fw, f, now);
    fw->cache_reply_len = n;
    if (f->type == FP_HELLO) {
        fw->cache_valid = 0; /* HELLO clears the stored request (a new host session) */
    } else {
        fw->cache_valid = 1;
        fw->cache_req.type = f->type;
        fw->cache_req.seq = f->seq;
        fw->cache_req.len = f->len;
        for (i = 0; i < f->len; ++i) {
            fw->cache_req.payload[i] = f->payload[i];
        }
    }
    hal_uart_write(fw->hal, fw->cache_reply, n);
}

void fw_rx_byte(fw_t *fw, uint8_t b)
{
    fp_frame f;
    fp_result r = fp_decoder_feed(&fw->dec, b, &f);
    if (r == FP_OK) {
        handle(fw, &f);
    } else if (r != FP_NONE && fw->rejects[r] < 0xFFFFu) {
        fw->rejects[r]++; /* rejected segments are dropped silently (SPEC.md section 5) */
    }
}
