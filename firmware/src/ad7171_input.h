/* The second AD7171 (issue 27): the engine-side input torque, on its own pins because the
 * AD7171 has no chip select (two cannot share SCLK): DOUT2/RDY2 on D8 = PB0 (PCINT0, its own
 * pin-change group: its RDY has its own vector and flag; and the ICP1 pin), SCLK2 on D9 = PB1
 * (Timer1 runs in normal mode: OC1A is not used). AVR only. */
#ifndef DYNO_AD7171_INPUT_H
#define DYNO_AD7171_INPUT_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif

/* Pins, SCLK idle high; DOUT2 with the pull-up on, so a missing converter reads "not ready". */
void ad7171_input_init(void);
/* DOUT2/RDY2 low: a conversion is waiting. */
uint8_t ad7171_input_ready(void);
/* Clock out 16 data bits then 8 status bits (MSB first). */
void ad7171_input_read(uint16_t *code, uint8_t *status);

#ifdef __cplusplus
}
#endif
#endif
