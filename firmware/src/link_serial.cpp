/* The same commands and frames as I2C, each packet COBS-encoded and ended by 0x00.
 * Runs in the main loop; the shared link state is touched only with interrupts off,
 * since the TWI ISR uses it too (one host at a time is expected, both are safe). */
#include <Arduino.h>
#include "link_serial.h"
#include "config.h"
extern "C" {
#include "cmd.h"
#include "cobs.h"
#include "crc16.h"
#include "frame.h"
#include "proto.h"
}

static uint8_t rx_buf[CMD_MAX_LEN + 2];  /* COBS adds one byte; one more = too long */
static uint8_t rx_len;
static bool rx_overrun;

void link_serial_init(void) { Serial.begin(SERIAL_BAUD); }

static void handle_packet(void)
{
    uint8_t cmd[CMD_MAX_LEN + 2];
    uint8_t n = cobs_decode(rx_buf, rx_len, cmd);
    if (n == 0xFF || n == 0)
        return;
    uint16_t residue = crc16(cmd, n);
    uint8_t sreg = SREG;
    cli();
    uint8_t op = proto_command(&g_proto, cmd, n, residue);
    SREG = sreg;
    if (op != OP_POLL && op != OP_ACK_POLL && op != OP_INFO && op != OP_CAPS)
        return;  /* SET_DEBOUNCE, CLEAR_COUNTERS, SET_CHANNELS and SET_SUPERVISOR get no answer */
    cli();
    const uint8_t *frame = proto_begin_read(&g_proto);
    SREG = sreg;
    uint8_t out[FRAME_MAX + 2];
    uint8_t len = cobs_encode(frame, frame[1], out);  /* L bytes, no padding */
    Serial.write(out, len);
    Serial.write((uint8_t)0);
    cli();
    proto_end_read(&g_proto);
    SREG = sreg;
}

void link_serial_service(void)
{
    while (Serial.available() > 0) {
        uint8_t b = (uint8_t)Serial.read();
        if (b == 0) {
            if (!rx_overrun && rx_len)
                handle_packet();
            rx_len = 0;
            rx_overrun = false;
        } else if (rx_len < sizeof rx_buf) {
            rx_buf[rx_len++] = b;
        } else {
            rx_overrun = true;  /* garbage: drop until the next 0x00 */
        }
    }
}
