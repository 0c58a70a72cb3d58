/* TWI slave for the v2 protocol: one combined transaction per poll,
 *   S addr+W <command> Sr addr+R <32 bytes> P
 *
 * Why not Wire: Wire's onRequest makes the sketch copy the reply into Wire's buffer
 * inside the ISR while SCL is held low, and Wire rejects reads longer than its buffer
 * anyway. Here every interrupt does O(1) work: a received byte updates a running CRC
 * (so the command check at the repeated start is one compare), and a read only points
 * at a frame the main loop already encoded (proto.c). Every TWI slave holds SCL low
 * from TWINT until the ISR clears it; keeping that short is what the Pi needs. */
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/twi.h>
#include "cmd.h"
#include "counters.h"
#include "crc16.h"
#include "frame.h"
#include "link_i2c.h"
#include "proto.h"

/* TWINT cleared (resume the bus), TWEA (ACK our address and data), interrupt on. */
#define TWCR_ACK (_BV(TWINT) | _BV(TWEA) | _BV(TWEN) | _BV(TWIE))

static uint8_t rx_buf[CMD_MAX_LEN];
static uint8_t rx_len;
static uint16_t rx_crc;
static const uint8_t *tx_buf;
static uint8_t tx_pos;

static uint8_t address_;

void link_i2c_init(uint8_t address)
{
    address_ = address;
    TWAR = (uint8_t)(address << 1);  /* no general call */
    TWSR = 0;
    TWCR = TWCR_ACK;
}

/* Slave timeout (like SMBus's 25 ms): a master that stops clocking mid-transfer leaves
 * a transmitting slave driving SDA (a 0 bit) for ever, and the bus dead. The main loop
 * watches the transfer's progress (no cost in the ISR); 25 ms without a TWI event while
 * a transfer is open disables the TWI unit (releasing SDA and SCL) and restarts it. The
 * frame that was being read counts as sent: the host did not acknowledge it, so it is
 * served again. */
void link_i2c_service(uint16_t now_ms)
{
    static uint8_t seen_pos, seen_len, watching;
    static uint16_t since_ms;
    uint8_t busy = g_proto.tx != PROTO_NONE || rx_len != 0;
    if (!busy) {
        watching = 0;
        return;
    }
    if (!watching || tx_pos != seen_pos || rx_len != seen_len) {
        watching = 1;
        seen_pos = tx_pos;
        seen_len = rx_len;
        since_ms = now_ms;
        return;
    }
    if ((uint16_t)(now_ms - since_ms) < I2C_SLAVE_TIMEOUT_MS)
        return;
    uint8_t sreg = SREG;
    cli();
    TWCR = 0;  /* TWI off: SDA and SCL released */
    rx_len = 0;
    proto_end_read(&g_proto);
    g_counters.twi_timeouts++;
    link_i2c_init(address_);
    SREG = sreg;
    watching = 0;
}

ISR(TWI_vect)
{
    switch (TW_STATUS) {
    case TW_SR_SLA_ACK:            /* 0x60 own SLA+W: a command follows */
    case TW_SR_ARB_LOST_SLA_ACK:
        rx_len = 0;
        rx_crc = CRC16_INIT;
        g_proto.tx = PROTO_NONE;   /* any earlier read is over, even if aborted */
        break;
    case TW_SR_DATA_ACK:           /* 0x80 command byte */
    case TW_SR_DATA_NACK: {
        uint8_t b = TWDR;
        if (rx_len < CMD_MAX_LEN)
            rx_buf[rx_len] = b;
        if (rx_len != 0xFF)
            rx_len++;
        rx_crc = crc16_update(rx_crc, b);
        break;
    }
    case TW_SR_STOP:               /* 0xA0 repeated start (or stop): command complete */
        if (rx_len)
            proto_command(&g_proto, rx_buf, rx_len, rx_crc);
        rx_len = 0;
        break;
    case TW_ST_SLA_ACK:            /* 0xA8 own SLA+R: first byte */
    case TW_ST_ARB_LOST_SLA_ACK:
        tx_buf = proto_begin_read(&g_proto);
        TWDR = tx_buf[0];
        tx_pos = 1;
        break;
    case TW_ST_DATA_ACK:           /* 0xB8 master wants more */
        /* Past 32 bytes (a host reading too much) send padding zeros, never RAM. */
        TWDR = tx_pos < FRAME_MAX ? tx_buf[tx_pos++] : 0;
        break;
    case TW_ST_DATA_NACK:          /* 0xC0 master's last byte */
    case TW_ST_LAST_DATA:
        proto_end_read(&g_proto);
        break;
    case TW_BUS_ERROR:             /* 0x00 illegal START/STOP: release the bus */
        g_counters.bus_errors++;
        TWCR = TWCR_ACK | _BV(TWSTO);
        return;
    default:
        break;
    }
    TWCR = TWCR_ACK;
}
