/*
 * hal_avr.c - ATmega328P (Arduino Uno/Nano, 16 MHz) HAL and main loop of the rig-controller firmware.
 * Pins (README.md in this folder has the wiring):
 *   PB1/OC1A (D9)  light driver PWM, Timer1 fast PWM 16-bit (TOP = 0xFFFF, 244 Hz)
 *   PB0 (D8)       light driver enable (high = on); the E-stop loop also breaks it in hardware
 *   PD7 (D7)       camera trigger output (high during the exposure)
 *   PD2 (D2)       E-stop loop, NC contact to GND, internal pull-up: high = pressed or wire broken
 *   PD3 (D3)       enclosure interlock, same wiring
 *   PC0/ADC0 (A0)  photodiode transimpedance amplifier output (0..5 V, AVCC reference)
 *   PC1/ADC1 (A1)  TMP36 on the light's heat sink (10 mV/degC, 500 mV at 0 degC)
 *   PD0/PD1        USART0, 115200 8N1
 * Timers: Timer0 1 kHz millisecond tick; Timer1 light PWM; Timer2 the one-shot trigger pulse, counted in
 * 0.5 us ticks (prescaler 8), the ISR latency compensated: the pulse lasts exposure_us to +-0.5 us
 * (pulses under ~3 us are ~3 us).
 * Hardware watchdog: enabled at boot (250 ms, reset mode) and fed by the main loop only (wdr once per
 * pass; the loop wakes at least every 1 ms on the Timer0 tick, and its longest step, a 255-sample
 * photodiode reading, takes ~35 ms): a hung main loop resets the chip, which leaves every pin an input
 * (the light's enable low: off). The cause of the last reset (MCUSR: watchdog, brown-out, external,
 * power-on) is kept for STATUS (SPEC.md section 4.5). With the optiboot boot loader MCUSR is cleared
 * before the application runs (optiboot passes it in r2; older boot loaders lose it): the cause then
 * reads "unknown" unless the boot loader hands it over.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "fw.h"

static volatile uint32_t ms_ticks;
#define TRIG_LATENCY_TICKS 4u
static volatile uint8_t trig_active;
static volatile uint32_t trig_chunks;
static volatile uint8_t cut_latch; /* set by the E-stop interrupt after it cut the light */

#define RX_SIZE 128u
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint16_t rx_errors; /* bytes received with a framing error or after an overrun, or dropped */

/* MCUSR as it was at reset, saved before anything else runs (avr-libc's <avr/wdt.h> recipe): after a
 * watchdog reset the watchdog stays enabled with its shortest period, so it is switched off at once. */
static uint8_t mcusr_at_reset __attribute__((section(".noinit")));
void save_mcusr(void) __attribute__((naked, used, section(".init3")));
void save_mcusr(void)
{
    mcusr_at_reset = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static uint8_t reset_cause(void)
{
    if (mcusr_at_reset & _BV(WDRF)) return FP_RESET_WATCHDOG;
    if (mcusr_at_reset & _BV(BORF)) return FP_RESET_BROWN_OUT;
    if (mcusr_at_reset & _BV(EXTRF)) return FP_RESET_EXTERNAL;
    if (mcusr_at_reset & _BV(PORF)) return FP_RESET_POWER_ON;
    return FP_RESET_UNKNOWN;
}

static int estop_pin(void) { return (PIND & _BV(PD2)) != 0; }
static int interlock_pin(void) { return (PIND & _BV(PD3)) != 0; }
static void estop_isr(void);

static void light_off_now(void)
{
    OCR1A = 0;
    TCCR1A &= (uint8_t)~_BV(COM1A1); /* PWM pin disconnected: held low */
    PORTB &= (uint8_t)~_BV(PB0);
}

/* E-stop or interlock open: cut the light and tell the main loop. Checked in the 1 kHz tick (so within
 * 1 ms whatever the main loop does); the NC loop also breaks the driver's enable in hardware at once.
 * (Not INT0/INT1: simavr 1.7 crashes on external-interrupt edges driven from outside.) */
static void estop_isr(void)
{
    if ((estop_pin() || interlock_pin()) && (PORTB & _BV(PB0))) {
        light_off_now();
        cut_latch = 1;
    }
}

ISR(TIMER0_COMPA_vect)
{
    ms_ticks++;
    estop_isr();
}

ISR(TIMER2_COMPA_vect)
{
    if (trig_chunks == 0u) {
        PORTD &= (uint8_t)~_BV(PD7);
        TCCR2B = 0;
        TIMSK2 &= (uint8_t)~_BV(OCIE2A);
        trig_active = 0;
    } else {
        OCR2A = 255; /* the remaining periods are 256 ticks each */
        trig_chunks--;
    }
}

/* One received byte. The error flags belong to the byte in UDR0 and must be read before it (datasheet
 * 20.7.4): a framing error or an overrun (bytes lost before this one) is counted; the byte is still passed
 * on, and the frame it belongs to fails its CRC check (SPEC.md section 2.4), so the decoder resynchronizes. */
ISR(USART_RX_vect)
{
    uint8_t st = UCSR0A;
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1u) % RX_SIZE);
    if (st & (_BV(FE0) | _BV(DOR0))) {
        rx_errors++;
    }
    if (next != rx_tail) {
        rx_buf[rx_head] = b;
        rx_head = next;
    } else {
        rx_errors++; /* ring full: the byte is lost and the frame fails its check */
    }
}

uint32_t hal_millis(fw_hal *h)
{
    uint32_t t;
    (void)h;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { t = ms_ticks; }
    return t;
}

/* Timer0 counts 250 steps of 4 us per millisecond tick; a compare match not yet serviced (OCF0A set,
 * interrupts blocked) means one more millisecond than ms_ticks says. */
uint32_t hal_micros(fw_hal *h)
{
    uint32_t ms;
    uint8_t t, pending;
    (void)h;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        ms = ms_ticks;
        t = TCNT0;
        pending = (TIFR0 & _BV(OCF0A)) != 0;
        if (pending && t < 249u) {
            ms++;
        }
    }
    return ms * 1000u + (uint32_t)t * 4u;
}

void hal_light_set(fw_hal *h, uint16_t duty)
{
    (void)h;
    if (duty == 0u || estop_pin() || interlock_pin()) {
        light_off_now();
        return;
    }
    OCR1A = duty;
    TCCR1A |= _BV(COM1A1);
    PORTB |= _BV(PB0);
}

int hal_estop_pressed(fw_hal *h) { (void)h; return estop_pin(); }
int hal_interlock_open(fw_hal *h) { (void)h; return interlock_pin(); }

static uint16_t adc(uint8_t ch)
{
    ADMUX = (uint8_t)(_BV(REFS0) | ch);
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

uint16_t hal_adc_photodiode(fw_hal *h) { (void)h; return adc(0); }

int16_t hal_temperature_centi(fw_hal *h)
{
    int32_t mv = (int32_t)adc(1) * 5000 / 1024; /* TMP36: (mV - 500) / 10 degC */
    (void)h;
    return (int16_t)((mv - 500) * 10);
}

void hal_trigger_start(fw_hal *h, uint32_t us)
{
    uint32_t ticks = us * 2u; /* 0.5 us ticks; us <= 600 000 000 fits */
    /* the falling edge is set by the compare ISR, a constant 4 ticks (2 us, 33 cycles: measured in simavr,
     * tests/protocol/test_simavr.py) after the match: count that much less, down to 1 tick */
    ticks = ticks > TRIG_LATENCY_TICKS ? ticks - TRIG_LATENCY_TICKS : 1u;
    uint16_t first = (uint16_t)(ticks & 0xFFu);
    (void)h;
    if (first == 0u) {
        first = 256u;
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        TCCR2B = 0;
        TCNT2 = 0;
        TCCR2A = _BV(WGM21); /* CTC */
        OCR2A = (uint8_t)(first - 1u);
        trig_chunks = (ticks - first) >> 8;
        TIFR2 = _BV(OCF2A);
        TIMSK2 |= _BV(OCIE2A);
        trig_active = 1;
        PORTD |= _BV(PD7);
        TCCR2B = _BV(CS21); /* start: clk/8 */
    }
}

int hal_trigger_active(fw_hal *h) { (void)h; return trig_active; }

void hal_uart_write(fw_hal *h, const uint8_t *p, size_t n)
{
    (void)h;
    while (n--) {
        while (!(UCSR0A & _BV(UDRE0))) {
        }
        UDR0 = *p++;
    }
}

static void hw_init(void)
{
    DDRB |= _BV(PB0) | _BV(PB1);
    PORTB &= (uint8_t)~(_BV(PB0) | _BV(PB1));
    DDRD |= _BV(PD7);
    PORTD &= (uint8_t)~_BV(PD7);
    DDRD &= (uint8_t)~(_BV(PD2) | _BV(PD3));
    PORTD |= _BV(PD2) | _BV(PD3); /* pull-ups: an open loop reads high */
    /* Timer0: CTC, clk/64, OCR0A = 249 -> 1 kHz */
    TCCR0A = _BV(WGM01);
    OCR0A = 249;
    TIMSK0 = _BV(OCIE0A);
    TCCR0B = _BV(CS01) | _BV(CS00);
    /* Timer1: fast PWM mode 14, TOP = ICR1 = 0xFFFF, clk/1, OC1A disconnected until the light is on */
    ICR1 = 0xFFFFu;
    OCR1A = 0;
    TCCR1A = _BV(WGM11);
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS10);
    /* ADC: AVCC reference, clk/128 (125 kHz) */
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
    /* USART0: 115200 8N1, double speed (UBRR 16: -2.1 %, 0.8 % with U2X at 16 MHz) */
    UCSR0A = _BV(U2X0);
    UBRR0 = 16;
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

static fw_t fw;

int main(void)
{
    fw_config cfg;
    uint8_t b;
    hw_init();
    fw_default_config(&cfg);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    fw_init(&fw, (fw_hal *)0, &cfg, reset_cause());
    wdt_enable(WDTO_250MS);
    for (;;) {
        wdt_reset(); /* the only place the hardware watchdog is fed: a hung main loop resets the chip */
        while (rx_tail != rx_head) {
            b = rx_buf[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1u) % RX_SIZE);
            fw_rx_byte(&fw, b);
        }
        if (cut_latch) {
            cut_latch = 0;
            fw_cut_light(&fw);
        }
        fw_poll(&fw);
        cli();
        if (rx_tail == rx_head) {
            sleep_enable(); /* idle until the next interrupt (UART byte, 1 ms tick) */
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
