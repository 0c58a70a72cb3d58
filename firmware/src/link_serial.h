/* v1 over USB serial: COBS packets terminated by 0x00 (docs/protocol.md). AVR only. */
#ifndef DYNO_LINK_SERIAL_H
#define DYNO_LINK_SERIAL_H
void link_serial_init(void);
void link_serial_service(void);
#endif
