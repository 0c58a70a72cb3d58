/* AD7171 16-bit ADC, bit-banged on D4 (SCLK) / D5 (DOUT/RDY). AVR only. */
#ifndef DYNO_AD7171_H
#define DYNO_AD7171_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif

/* The AD7171's status byte: the third bit clocked after the data is its error flag. */
#define AD7171_STATUS_ERR 0x20u

void ad7171_init(void);
/* DOUT/RDY low: a conversion is waiting to be clocked out. */
uint8_t ad7171_ready(void);
/* Clock out 16 data bits then the 8 status bits (MSB first); keeps the status as is. */
void ad7171_read(uint16_t *code, uint8_t *status);

#ifdef __cplusplus
}
#endif
#endif
