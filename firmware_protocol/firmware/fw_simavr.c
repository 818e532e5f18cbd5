/*
 * fw_simavr.c - run the firmware's AVR build (build/goniofw.elf) in simavr, an emulated ATmega328P at
 * 16 MHz, in lockstep with the simulator's clock (sim/simavr.py drives it; one process per controller).
 *
 * Commands on stdin, one per line; the bridge answers each RUN/RX with its events and "IDLE <us>":
 *   RUN <us>          run the firmware until its emulated time (us since its power-on) reaches <us>, as fast
 *                     as the host CPU allows (no real-time pacing: emulated time is the caller's clock)
 *   RX <hex>          bytes from the host: fed to USART0 at the wire's pace (one byte per 10 bit times of the
 *                     programmed baud rate) from the current emulated time; then the firmware runs until it
 *                     is asleep again with every byte taken (its reply written), at most 2 s of emulated time
 *   ESTOP 0|1         close / open the E-stop loop (pin PD2 high = pressed)
 *   INTERLOCK 0|1     close / open the enclosure interlock (pin PD3 high = open)
 *   TEMP <centi-degC> the TMP36 on the heat sink (ADC1 = 500 mV + 10 mV/degC)
 *   PD <noise_e6> <depth_e6> <tau_ms>  photodiode model: noise sigma, warm-up deficit d and time constant
 *   SEED <n>          restart the photodiode noise generator (xorshift64*, Box-Muller) from n
 *   TICKS <addr>      the data address of the firmware's millisecond counter (ms_ticks, from avr-nm): lets RUN
 *                     skip idle time (below)
 *   HANG              make the main loop hang (a test of the hardware watchdog: the bridge writes an endless
 *                     loop into free flash and jumps there; interrupts keep running, nothing feeds WDT)
 * Idle time: while the CPU sleeps with nothing pending, nothing happens but the 1 kHz Timer0 tick (its ISR
 * counts ms_ticks and samples the E-stop pins, which do not change during a RUN). RUN then skips up to 100 ms
 * at once: the cycle counter and every pending simavr timer move k whole milliseconds later (so each timer's
 * phase, Timer0's count included, is what it would have been) and ms_ticks gets the k ticks; the firmware then
 * wakes at its next tick as it would have, and runs a pass of its main loop (which feeds the 250 ms hardware
 * watchdog) before the next skip. The firmware sees the times it would have seen, about 100 times faster.
 * Events on stdout: "TX <hex>" (bytes the firmware sent), "LIGHT <duty> <on_since_us>" when the PWM duty
 * changes, "PULSE <ns>" per trigger pulse on PD7, "IDLE <us>" (emulated time since power-on) after each command.
 * End of stdin (the parent died or closed it) ends the bridge.
 *
 * Physics at each ADC conversion: photodiode (ADC0) = PD_FULL_MV * duty/65535 * (1 - d exp(-(t - t_on)/tau))
 * + N(0, sigma) (the model of sim/controller.py: first-order warm-up of the lamp, Gaussian noise; t_on is when
 * the duty last went from 0 to non-zero), clamped to 0..5000 mV; the noise is drawn for photodiode
 * conversions only, so a seed gives the same readings whatever else the firmware converts.
 * Usage: fw_simavr FIRMWARE.elf
 */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <simavr/avr_adc.h>
#include <simavr/avr_extint.h>
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_interrupts.h>

#define PD_FULL_MV 4395.0 /* 900 counts of 1024 at 5 V: the firmware's pd_full_counts */
#define R_OCR1AL 0x88
#define R_OCR1AH 0x89
#define R_TCCR1A 0x80
#define R_ADMUX 0x7C
#define R_UBRR0L 0xC4
#define R_UBRR0H 0xC5
#define R_UCSR0A 0xC0

static avr_t *avr;
static uint32_t estop, interlock;
static long temp_centi = 2500;
static double pd_noise = 0.0, pd_depth = 0.0, pd_tau_s = 120.0;
static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static uint32_t duty_reported;
static avr_cycle_count_t on_since;
static int light_was_on;
static uint32_t ticks_addr; /* data address of ms_ticks (0: no idle skipping) */
static uint8_t tx[4096];
static size_t tx_n;

static double now_us(void) { return (double)avr->cycle * 1e6 / (double)avr->frequency; }

static uint32_t duty_now(void)
{
    uint16_t ocr = (uint16_t)(avr->data[R_OCR1AL] | (avr->data[R_OCR1AH] << 8));
    return (avr->data[R_TCCR1A] & 0x80) ? ocr : 0u; /* COM1A1: the PWM pin is connected */
}

/* the light's duty: note switch-on instants (warm-up) and report changes */
static void track_light(void)
{
    uint32_t d = duty_now();
    if (d && !light_was_on) {
        on_since = avr->cycle;
    }
    light_was_on = d != 0u;
    if (d != duty_reported) {
        duty_reported = d;
        printf("LIGHT %u %.0f\n", (unsigned)d, (double)on_since * 1e6 / (double)avr->frequency);
    }
}

/* xorshift64* (Vigna 2016) and Box-Muller: reproducible Gaussian noise from a seed */
static double uniform01(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return ((rng_state * 0x2545F4914F6CDD1Dull) >> 11) * (1.0 / 9007199254740992.0);
}

static double gauss(void)
{
    double u = uniform01(), v = uniform01();
    return sqrt(-2.0 * log(u > 0.0 ? u : 1e-300)) * cos(2.0 * M_PI * v);
}

static void adc_trigger(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    track_light();
    if ((avr->data[R_ADMUX] & 0x0F) == 0) { /* the photodiode: the only channel that draws noise */
        double t = (double)(avr->cycle - on_since) / (double)avr->frequency;
        double rel = duty_now() / 65535.0 * (1.0 - pd_depth * exp(-t / pd_tau_s));
        double mv = PD_FULL_MV * rel + (pd_noise > 0.0 ? PD_FULL_MV * pd_noise * gauss() : 0.0);
        mv = mv < 0.0 ? 0.0 : mv > 5000.0 ? 5000.0 : mv;
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0), (uint32_t)(mv + 0.5));
    } else {
        long mv = 500 + temp_centi / 10;
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC1), (uint32_t)(mv < 0 ? 0 : mv));
    }
}

static avr_cycle_count_t rise;
static void trigger_edge(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (value) {
        rise = avr->cycle;
    } else if (rise) {
        printf("PULSE %llu\n", (unsigned long long)((avr->cycle - rise) * 1000000000ull / avr->frequency));
        rise = 0;
    }
}

static void uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (tx_n < sizeof tx) {
        tx[tx_n++] = (uint8_t)value;
    }
}

static void flush_tx(void)
{
    size_t i;
    if (!tx_n) {
        return;
    }
    printf("TX ");
    for (i = 0; i < tx_n; ++i) {
        printf("%02x", tx[i]);
    }
    printf("\n");
    tx_n = 0;
}

/* no real-time pacing while the CPU sleeps: emulated time is the caller's clock (RUN) */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a; (void)how_long; }

static void pins(void)
{
    /* the loops are driven by their contacts, not by the pull-ups the firmware sets: assert them */
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2), estop);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3), interlock);
}

static avr_cycle_count_t last_pc_cycle;
static int step(void)
{
    int state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) {
        fprintf(stderr, "simavr: the firmware stopped (state %d)\n", state);
        exit(1);
    }
    if (avr->cycle - last_pc_cycle >= 16000u) { /* every emulated ms */
        last_pc_cycle = avr->cycle;
        pins();
        track_light();
    }
    return state;
}

static void skip_idle(avr_cycle_count_t target)
{
    const avr_cycle_count_t ms = avr->frequency / 1000u;
    avr_cycle_count_t k = (target - avr->cycle) / ms;
    avr_cycle_timer_slot_p slot;
    uint32_t t;
    if (!ticks_addr || k < 3u || avr->state != cpu_Sleeping || avr_has_pending_interrupts(avr) ||
        (avr->data[0x2B] & 0x80)) { /* PD7 high: a trigger pulse is timing on Timer2 */
        return;
    }
    k = (k - 2u) > 100u ? 100u : k - 2u;
    avr->cycle += k * ms;
    for (slot = avr->cycle_timers.timer; slot; slot = slot->next) {
        slot->when += k * ms;
    }
    t = (uint32_t)avr->data[ticks_addr] | (uint32_t)avr->data[ticks_addr + 1u] << 8 |
        (uint32_t)avr->data[ticks_addr + 2u] << 16 | (uint32_t)avr->data[ticks_addr + 3u] << 24;
    t += (uint32_t)k;
    avr->data[ticks_addr] = (uint8_t)t;
    avr->data[ticks_addr + 1u] = (uint8_t)(t >> 8);
    avr->data[ticks_addr + 2u] = (uint8_t)(t >> 16);
    avr->data[ticks_addr + 3u] = (uint8_t)(t >> 24);
}

static void run_until(avr_cycle_count_t target)
{
    while (avr->cycle < target) {
        skip_idle(target);
        step();
    }
}

static avr_cycle_count_t cycles_per_byte(void)
{
    uint32_t ubrr = (uint32_t)(avr->data[R_UBRR0L] | (avr->data[R_UBRR0H] << 8));
    uint32_t per_bit = (ubrr + 1u) * ((avr->data[R_UCSR0A] & 0x02) ? 8u : 16u); /* U2X0 */
    return (avr_cycle_count_t)per_bit * 10u; /* start + 8 data + stop */
}

static void receive(const char *hex)
{
    avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_cycle_count_t next = avr->cycle, limit = avr->cycle + 2u * (avr_cycle_count_t)avr->frequency;
    unsigned b;
    while (sscanf(hex, "%2x", &b) == 1) {
        hex += 2;
        run_until(next);
        avr_raise_irq(in, b); /* the wire delivers one byte per byte time: a slow firmware loses bytes */
        next = avr->cycle + cycles_per_byte();
    }
    run_until(next + 2u * cycles_per_byte()); /* simavr raises RXC one byte time after the byte arrives */
    /* until the reply is written and the main loop sleeps with nothing pending (every byte taken) */
    while (avr->cycle < limit && (step() != cpu_Sleeping || avr_has_pending_interrupts(avr))) {
    }
}

static void hang(void)
{
    /* "rjmp .-2" (0xCFFF) in the last word of flash (the boot loader's area, unused here); jump there */
    uint32_t at = avr->flashend - 1u;
    avr->flash[at] = 0xFF;
    avr->flash[at + 1u] = 0xCF;
    avr->pc = at;
}

int main(int argc, char **argv)
{
    elf_firmware_t f;
    char line[8192];
    uint32_t flags = 0;
    memset(&f, 0, sizeof f);
    if (argc != 2 || elf_read_firmware(argv[1], &f) != 0) {
        fprintf(stderr, "usage: %s FIRMWARE.elf (a readable AVR ELF)\n", argv[0]);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "simavr has no atmega328p core\n");
        return 2;
    }
    avr_init(avr);
    avr->log = getenv("FW_SIMAVR_LOG") ? 3 : 1;
    avr->vcc = avr->avcc = avr->aref = 5000; /* mV: an Uno's 5 V supply and AVCC reference */
    f.frequency = 16000000;
    avr_load_firmware(avr, &f);
    avr->sleep = no_sleep;
    /* INT0/INT1 (PD2, PD3: the E-stop and interlock loops, held low while closed) are not used by the firmware,
     * but simavr re-checks a low pin of a "strict" level-triggered INT every cycle, enabled or not: 10 times
     * slower emulation while the CPU sleeps */
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 7), trigger_edge, NULL);
    pins();
    printf("READY\n");
    fflush(stdout);
    while (fgets(line, sizeof line, stdin)) {
        double v1 = 0, v2 = 0, v3 = 0;
        unsigned long long n;
        long long c;
        if (sscanf(line, "RUN %llu", &n) == 1) {
            run_until((avr_cycle_count_t)(n * (avr->frequency / 1000000u)));
        } else if (strncmp(line, "RX ", 3) == 0) {
            receive(line + 3);
        } else if (sscanf(line, "ESTOP %llu", &n) == 1) {
            estop = n != 0u;
            pins();
        } else if (sscanf(line, "INTERLOCK %llu", &n) == 1) {
            interlock = n != 0u;
            pins();
        } else if (sscanf(line, "TEMP %lld", &c) == 1) {
            temp_centi = (long)c;
        } else if (sscanf(line, "PD %lf %lf %lf", &v1, &v2, &v3) == 3) {
            pd_noise = v1 * 1e-6;
            pd_depth = v2 * 1e-6;
            pd_tau_s = v3 > 0 ? v3 * 1e-3 : 120.0;
        } else if (sscanf(line, "SEED %llu", &n) == 1) {
            rng_state = (uint64_t)n ^ 0x9E3779B97F4A7C15ull;
            if (!rng_state) {
                rng_state = 1u;
            }
        } else if (sscanf(line, "TICKS %llu", &n) == 1) {
            ticks_addr = n + 3u < avr->ramend ? (uint32_t)n : 0u;
        } else if (strncmp(line, "HANG", 4) == 0) {
            hang();
        } else {
            fprintf(stderr, "fw_simavr: unknown command %.40s", line);
        }
        track_light();
        flush_tx();
        printf("IDLE %.0f\n", now_us());
        fflush(stdout);
    }
    return 0; /* end of stdin: the parent is gone */
}
