#include <avr/eeprom.h>
#include "bootcount.h"
#include "config.h"

uint16_t bootcount_increment(void)
{
    uint16_t *addr = (uint16_t *)(uintptr_t)EEPROM_BOOTCOUNT_ADDR;
    uint16_t n = eeprom_read_word(addr);
    if (n == 0xFFFFu)  /* erased EEPROM */
        n = 0;
    n++;
    /* One write per boot: 100k EEPROM cycles are a lifetime of power cycles. */
    eeprom_update_word(addr, n);
    return n;
}
