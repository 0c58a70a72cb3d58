/* I2C slave link (TWI hardware, own driver: no Wire, no copying in the ISR). AVR only. */
#ifndef DYNO_LINK_I2C_H
#define DYNO_LINK_I2C_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif
void link_i2c_init(uint8_t address);
#ifdef __cplusplus
}
#endif
#endif
