/* Hall edge capture on INT0/INT1 with Timer1-extended timestamps (AVR only). */
#ifndef DYNO_CAPTURE_H
#define DYNO_CAPTURE_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif

void capture_init(uint16_t lockout_primary_us, uint16_t lockout_secondary_us);
/* Device time in us (u32, wraps at 2^32), safe from any context. */
uint32_t capture_now_us(void);
/* Main loop housekeeping (keeps the lock-out logic right across 2^32 us). */
void capture_service(void);
/* Time of the AD7171's last RDY falling edge (pin change ISR), or now if none was seen;
 * then re-arm the RDY interrupt once the result was clocked out. */
uint32_t capture_adc_rdy_us(void);
void capture_adc_rearm(void);
/* Enqueue an ADC conversion from the main loop (interrupts briefly off). */
void capture_push_adc(uint32_t t_us, uint16_t code, uint8_t status);
/* The input torque converter (issue 27): RDY2's falling edge on PB0 (PCINT0), timed as the first
 * converter's. capture_input_arm() after the boot probe found it and after every read (the data bits
 * toggle the same pin); capture_input_rdy_us() the time of the RDY being read (DOUT2 is low). */
void capture_input_arm(void);
uint32_t capture_input_rdy_us(void);
void capture_push_input(uint32_t t_us, uint16_t code, uint8_t status);
void capture_set_lockout(uint16_t primary_us, uint16_t secondary_us);
/* Main loop, for the run-enable supervisor: the channels (bit 0 primary, bit 1 secondary) whose period
 * between two accepted pulses capture_service measured since the last call; that period (us) and the
 * accepted pulse that ended it (its falling edge's time). */
uint8_t capture_take_periods(void);
uint32_t capture_period_us(uint8_t ch);
uint32_t capture_last_us(uint8_t ch);

/* Rejected edges are counted per cause in g_counters (counters.h). */

#ifdef __cplusplus
}
#endif
#endif
