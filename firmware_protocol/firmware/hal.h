/*
 * hal.h - the hardware abstraction the rig-controller firmware (fw.c) runs on.
 *
 * Four kinds of hardware, each behind a few functions: pins (light enable/PWM, E-stop and interlock
 * inputs, trigger output), ADC (photodiode, temperature), timer (milliseconds since power-on, the
 * one-shot trigger pulse) and UART (transmit; received bytes are pushed into fw_rx_byte()).
 * Builds: hal_host.c (shared library driven by sim/firmware.py, simulated time), hal_avr.c (ATmega328P).
 * Every function takes the build's opaque context (ignored on the AVR, one instance per process
 * elsewhere), so a host process can run several controllers at once.
 */
#ifndef FW_HAL_H
#define FW_HAL_H

#include <stddef.h>
#include <stdint.h>

typedef struct fw_hal fw_hal;

uint32_t hal_millis(fw_hal *h);                    /* ms since power-on; wraps after 49.7 days */
uint32_t hal_micros(fw_hal *h);                    /* us since power-on, for intervals; wraps after 71.6 min */
void hal_light_set(fw_hal *h, uint16_t duty);      /* light driver PWM duty 0..65535; 0 = driver disabled */
int hal_estop_pressed(fw_hal *h);                  /* 1 while the E-stop loop is open (NC contact broken) */
int hal_interlock_open(fw_hal *h);                 /* 1 while the enclosure interlock is open */
uint16_t hal_adc_photodiode(fw_hal *h);            /* one photodiode conversion, raw counts */
int16_t hal_temperature_centi(fw_hal *h);          /* light-source temperature, 0.01 degC */
void hal_trigger_start(fw_hal *h, uint32_t us);    /* raise the trigger line for exactly us microseconds */
int hal_trigger_active(fw_hal *h);                 /* 1 while the trigger line is high */
void hal_uart_write(fw_hal *h, const uint8_t *p, size_t n);

#endif
