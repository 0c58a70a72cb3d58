/* EEPROM boot counter: a watchdog reset shows up on the host as a new boot. */
#ifndef DYNO_BOOTCOUNT_H
#define DYNO_BOOTCOUNT_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {
#endif
/* Increments and returns the stored count (erased EEPROM counts as 0). */
uint16_t bootcount_increment(void);
#ifdef __cplusplus
}
#endif
#endif
