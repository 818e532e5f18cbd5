/*
 * hal_host.c - host build of the HAL: the firmware as a shared library (libgoniofw.so) driven by
 * sim/firmware.py over ctypes. Time is whatever the host sets (the simulator's Clock), the UART
 * transmit goes to a buffer the host drains, the ADC and the temperature sensor call back into the
 * simulator's physics, the pins are fields the host sets (E-stop, interlock) or reads (PWM duty,
 * trigger). One fwhost per emulated controller; no globals.
 */
#include <stdlib.h>
#include <string.h>

#include "fw.h"

typedef uint16_t (*adc_fn)(void *ctx);
typedef int16_t (*temp_fn)(void *ctx);

struct fw_hal {
    uint64_t now_us;          /* simulated time, set by the host */
    uint64_t on_since_us;     /* when the PWM duty last went from 0 to non-zero */
    uint64_t trigger_end_us;
    uint64_t trigger_start_us;
    uint16_t duty;
    uint8_t estop, interlock, brownout;
    adc_fn adc;
    temp_fn temp;
    void *ctx;
    size_t tx_n;
    uint8_t tx[4096];
};

typedef struct {
    fw_hal hal;
    fw_t fw;
} fwhost;

uint32_t hal_millis(fw_hal *h) { return (uint32_t)(h->now_us / 1000u); }
uint32_t hal_micros(fw_hal *h) { return (uint32_t)h->now_us; }

void hal_light_set(fw_hal *h, uint16_t duty)
{
    if (duty && !h->duty) {
        h->on_since_us = h->now_us;
    }
    h->duty = duty;
}

int hal_estop_pressed(fw_hal *h) { return h->estop; }
int hal_interlock_open(fw_hal *h) { return h->interlock; }
uint16_t hal_adc_photodiode(fw_hal *h) { return h->adc ? h->adc(h->ctx) : 0u; }
int16_t hal_temperature_centi(fw_hal *h) { return h->temp ? h->temp(h->ctx) : 2500; }

void hal_trigger_start(fw_hal *h, uint32_t us)
{
    h->trigger_start_us = h->now_us;
    h->trigger_end_us = h->now_us + us;
}

int hal_trigger_active(fw_hal *h) { return h->now_us < h->trigger_end_us; }

void hal_uart_write(fw_hal *h, const uint8_t *p, size_t n)
{
    if (h->tx_n + n <= sizeof h->tx) {
        memcpy(&h->tx[h->tx_n], p, n);
        h->tx_n += n;
    }
}

int hal_host_brownout(fw_hal *h)
{
    int b = h->brownout;
    h->brownout = 0;
    return b;
}

/* -- the host's interface (sim/firmware.py) ------------------------------------------------------ */
fwhost *fwhost_new(const fw_config *cfg, uint64_t now_us, adc_fn adc, temp_fn temp, void *ctx)
{
    fwhost *x = (fwhost *)calloc(1, sizeof *x);
    if (!x) {
        return NULL;
    }
    x->hal.now_us = now_us;
    x->hal.adc = adc;
    x->hal.temp = temp;
    x->hal.ctx = ctx;
    fw_init(&x->fw, &x->hal, cfg, FP_RESET_POWER_ON);
    return x;
}

void fwhost_free(fwhost *x) { free(x); }
void fwhost_default_config(fw_config *c) { fw_default_config(c); }
size_t fwhost_config_size(void) { return sizeof(fw_config); }

void fwhost_set_time(fwhost *x, uint64_t now_us)
{
    if (now_us > x->hal.now_us) {
        x->hal.now_us = now_us;
    }
    fw_poll(&x->fw);
}

void fwhost_reset(fwhost *x)
{
    fw_config c = x->fw.cfg;
    x->hal.trigger_end_us = 0;
    fw_init(&x->fw, &x->hal, &c, FP_RESET_EXTERNAL);
}

void fwhost_brownout(fwhost *x) { x->hal.brownout = 1; }

void fwhost_set_inputs(fwhost *x, int estop, int interlock)
{
    x->hal.estop = (uint8_t)(estop != 0);
    x->hal.interlock = (uint8_t)(interlock != 0);
    fw_estop_event(&x->fw); /* the pin-change interrupt */
}

/* Feed received bytes; returns how many reply bytes are waiting (fwhost_take_tx). */
size_t fwhost_rx(fwhost *x, const uint8_t *p, size_t n)
{
    size_t i;
    for (i = 0; i < n; ++i) {
        fw_rx_byte(&x->fw, p[i]);
    }
    return x->hal.tx_n;
}

size_t fwhost_take_tx(fwhost *x, uint8_t *out, size_t cap)
{
    size_t n = x->hal.tx_n < cap ? x->hal.tx_n : cap;
    memcpy(out, x->hal.tx, n);
    memmove(x->hal.tx, x->hal.tx + n, x->hal.tx_n - n);
    x->hal.tx_n -= n;
    return n;
}

/* Observables: [duty, light_on, level, tripped, configured, trigger_count, executed, duplicates,
 * watchdog_ms, pd_time_ms, on_since_us(hal), trigger_start_us, trigger_end_us, pd_span_us, session_minor,
 * overtemp, reset_cause] */
void fwhost_state(fwhost *x, uint64_t *s)
{
    s[0] = x->hal.duty;
    s[1] = x->fw.light_on;
    s[2] = x->fw.level;
    s[3] = x->fw.tripped;
    s[4] = x->fw.configured;
    s[5] = x->fw.trigger_count;
    s[6] = 0; /* see fwhost_executed */
    s[7] = x->fw.duplicates;
    s[8] = x->fw.watchdog_ms;
    s[9] = x->fw.pd_time_ms;
    s[10] = x->hal.on_since_us;
    s[11] = x->hal.trigger_start_us;
    s[12] = x->hal.trigger_end_us;
    s[13] = x->fw.pd_span_us;
    s[14] = x->fw.session_minor;
    s[15] = x->fw.overtemp;
    s[16] = x->fw.reset_cause;
}

uint32_t fwhost_executed(fwhost *x, uint8_t type) { return type < 8u ? x->fw.executed[type] : 0u; }

/* Rejected segments by verdict: overflow, crc, cobs, length (the Python Decoder's order). */
void fwhost_rejects(fwhost *x, uint32_t *r)
{
    r[0] = x->fw.rejects[FP_REJ_OVERFLOW];
    r[1] = x->fw.rejects[FP_REJ_CRC];
    r[2] = x->fw.rejects[FP_REJ_COBS];
    r[3] = x->fw.rejects[FP_REJ_LENGTH];
}
