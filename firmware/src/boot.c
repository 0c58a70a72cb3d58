#include <avr/io.h>
#include <avr/wdt.h>
#include "boot.h"
#include "crc16.h"

uint16_t g_boot_id __attribute__((section(".noinit")));
uint8_t g_reset_cause __attribute__((section(".noinit")));

/* .init3 runs after the stack is set up and before .data/.bss are initialised: all of
 * SRAM is still as the reset left it. Naked and call-free (no return address yet). A
 * watchdog reset leaves the WDT running at its shortest timeout, so it is stopped here,
 * before init() and the constructors. */
void boot_init3(void) __attribute__((naked, used, section(".init3")));
void boot_init3(void)
{
    uint8_t cause = MCUSR;
    if (!cause)
        __asm__ volatile("mov %0, r2" : "=r"(cause));  /* Optiboot's hand-over */
    MCUSR = 0;
    wdt_disable();
    cause &= 0x0F;
    g_reset_cause = cause;
    if (cause & (_BV(PORF) | _BV(BORF)) || !cause) {
        uint16_t h = CRC16_INIT;
        for (const volatile uint8_t *p = (const volatile uint8_t *)RAMSTART;
             p <= (const volatile uint8_t *)RAMEND; p++)
            h = crc16_update(h, *p);
        g_boot_id = (uint16_t)(h ^ g_boot_id);
    }
    g_boot_id++;
}
