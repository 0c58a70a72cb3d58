/* The only platform dependence of the shared modules: a critical section. On the AVR it
 * saves SREG and disables interrupts (callable from ISR or main loop); natively (unit
 * tests, single threaded) it is empty. */
#ifndef DYNO_PORT_H
#define DYNO_PORT_H
#ifdef __AVR__
#include <avr/io.h>
#include <avr/interrupt.h>
#define PORT_CRITICAL_BEGIN() do { uint8_t port_sreg_ = SREG; cli()
#define PORT_CRITICAL_END() SREG = port_sreg_; } while (0)
#else
#define PORT_CRITICAL_BEGIN() do {
#define PORT_CRITICAL_END() } while (0)
#endif
#endif
