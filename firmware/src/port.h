/* The only platform dependence of the shared modules: a critical section and constant
 * tables in flash. On the AVR the critical section saves SREG and disables interrupts
 * (callable from ISR or main loop) and tables live in program memory (read with LPM);
 * natively (unit tests, single threaded) both are plain C. */
#ifndef DYNO_PORT_H
#define DYNO_PORT_H
#ifdef __AVR__
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/pgmspace.h>
#define PORT_CRITICAL_BEGIN() do { uint8_t port_sreg_ = SREG; cli()
#define PORT_CRITICAL_END() SREG = port_sreg_; } while (0)
#define PORT_FLASH PROGMEM
#define PORT_FLASH_U32(addr) pgm_read_dword(addr)
#else
#define PORT_CRITICAL_BEGIN() do {
#define PORT_CRITICAL_END() } while (0)
#define PORT_FLASH
#define PORT_FLASH_U32(addr) (*(addr))
#endif
#endif
