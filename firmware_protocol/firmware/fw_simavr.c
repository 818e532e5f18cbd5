/*
 * fw_simavr.c - run the firmware's AVR build (build/goniofw.elf) in simavr, an emulated ATmega328P at
 * 16 MHz, with USART0 on a pseudo-terminal (simavr's uart_pty part). Prints "PTY <path>" on stdout
 * once the pty exists. The analogue side is a model: at every ADC conversion the photodiode input
 * (ADC0) is set to PD_FULL_MV * duty / 65535 from the light's PWM registers (OCR1A, COM1A1), the
 * TMP36 (ADC1) to 750 mV (25 degC); "LIGHT <duty>" lines on stdout report the PWM duty as it changes,
 * "PULSE <ns>" the length of each trigger pulse on PD7 in emulated time. SIGUSR1 opens the E-stop loop (pin PD2 high), SIGUSR2 closes it.
 * Usage: fw_simavr FIRMWARE.elf
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <simavr/avr_adc.h>
#include <simavr/avr_ioport.h>
#include <simavr/parts/uart_pty.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

#define PD_FULL_MV 4395 /* 900 counts of 1024 at 5 V: the firmware's pd_full_counts */

static avr_t *avr;
static uart_pty_t uart;
static volatile sig_atomic_t estop_req = -1;

static void on_sig(int s) { estop_req = (s == SIGUSR1); }

static void adc_trigger(struct avr_irq_t *irq, uint32_t value, void *param)
{
    uint16_t ocr = (uint16_t)(avr->data[0x88] | (avr->data[0x89] << 8)); /* OCR1A */
    int on = (avr->data[0x80] & 0x80) != 0;                               /* TCCR1A.COM1A1 */
    uint32_t mv = on ? (uint32_t)((uint64_t)PD_FULL_MV * ocr / 65535u) : 0u;
    (void)irq; (void)value; (void)param;
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0), mv);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC1), 750);
}

/* the trigger line PD7: report each pulse's length in emulated time ("PULSE <ns>") */
static avr_cycle_count_t rise;
static void trigger_edge(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (value) {
        rise = avr->cycle;
    } else if (rise) {
        printf("PULSE %llu\n", (unsigned long long)((avr->cycle - rise) * 1000000000ull / avr->frequency));
        fflush(stdout);
        rise = 0;
    }
}

int main(int argc, char **argv)
{
    elf_firmware_t f;
    int state;
    uint32_t estop = 0, n = 0, reported = 0;
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
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 7), trigger_edge, NULL);
    uart_pty_init(avr, &uart);
    uart_pty_connect(&uart, '0');
    /* the E-stop loop and the interlock are closed (NC contacts to GND): drive PD2 and PD3 low */
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2), 0);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3), 0);
    printf("PTY %s\n", uart.pty.slavename);
    fflush(stdout);
    signal(SIGUSR1, on_sig);
    signal(SIGUSR2, on_sig);
    signal(SIGTERM, exit);
    for (;;) {
        if (estop_req >= 0) {
            estop = (uint32_t)estop_req;
            estop_req = -1;
        }
        /* the loops are driven by their contacts, not by the pull-ups the firmware sets: re-assert */
        if ((++n & 0x3FFu) == 0u) {
            /* report the light's PWM duty when it changes ("LIGHT <duty>"), for the simulated camera */
            uint16_t ocr = (uint16_t)(avr->data[0x88] | (avr->data[0x89] << 8));
            uint32_t duty = (avr->data[0x80] & 0x80) ? ocr : 0u;
            if (duty != reported) {
                reported = duty;
                printf("LIGHT %u\n", (unsigned)duty);
                fflush(stdout);
            }
            avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2), estop);
            avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3), 0);
        }
        state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "simavr: the firmware stopped (state %d)\n", state);
            return 1;
        }
    }
}
