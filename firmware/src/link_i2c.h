/* I2C slave link (TWI hardware, own driver: no Wire, no copying in the ISR). AVR only. */
#ifndef DYNO_LINK_I2C_H
#define DYNO_LINK_I2C_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif
void link_i2c_init(uint8_t address);
/* Main loop: the 25 ms slave timeout (releases a bus a master left mid-transfer). */
void link_i2c_service(uint16_t now_ms);
#ifdef __cplusplus
}
#endif
#endif
