/* A small sketch that speaks the thesis rig's legacy 20-byte I2C frame (protocol v0,
 * docs/protocol.md), written for the firmware-in-the-loop tests of `--protocol v0`.
 * Same behaviour as the thesis's Appendix G sketch (Wire slave at 0x03, micros()
 * timestamps, latest value per slot, debounce 10/6 ms, ADC polled in loop()), but
 * written afresh: wrap-safe debounce and slots updated atomically. */
#include <Arduino.h>
#include <Wire.h>

static const uint8_t PIN_SCLK = 4, PIN_DOUT = 5;
static const unsigned long LOCKOUT_PRIMARY_US = 10000, LOCKOUT_SECONDARY_US = 6000;

/* The 18 data bytes, big-endian: rpm_p, t_p, rpm_s, t_s, adc, t_adc. */
static volatile uint8_t slots[18];
static volatile unsigned long last_p_us, last_s_us;
static volatile bool seen_p, seen_s;

static void put16(uint8_t at, uint16_t v)
{
    slots[at] = (uint8_t)(v >> 8);
    slots[at + 1] = (uint8_t)v;
}

static void put32(uint8_t at, uint32_t v)
{
    for (uint8_t i = 0; i < 4; i++)
        slots[at + i] = (uint8_t)(v >> (24 - 8 * i));
}

static void edge(uint8_t at, volatile unsigned long &last, volatile bool &seen, unsigned long lockout)
{
    unsigned long now = micros();
    unsigned long period = now - last;
    if (seen && period < lockout)
        return;  /* bounce */
    put16(at, seen && period ? (uint16_t)(60000000UL / period) : 0);
    put32(at + 2, now);
    last = now;
    seen = true;
}

static void on_primary() { edge(0, last_p_us, seen_p, LOCKOUT_PRIMARY_US); }
static void on_secondary() { edge(6, last_s_us, seen_s, LOCKOUT_SECONDARY_US); }

/* Runs in the TWI ISR: the slots cannot change underneath (ISRs do not nest). */
static void on_request()
{
    uint8_t out[20];
    uint16_t sum = 0;
    for (uint8_t i = 0; i < 18; i++) {
        out[i] = slots[i];
        sum += out[i];
    }
    out[18] = (uint8_t)(sum >> 8);
    out[19] = (uint8_t)sum;
    Wire.write(out, 20);
}

void setup()
{
    pinMode(PIN_SCLK, OUTPUT);
    digitalWrite(PIN_SCLK, HIGH);
    pinMode(PIN_DOUT, INPUT);
    put16(0, 100);  /* the thesis sketch's initial rpm values */
    put16(6, 100);
    attachInterrupt(digitalPinToInterrupt(2), on_primary, FALLING);
    attachInterrupt(digitalPinToInterrupt(3), on_secondary, FALLING);
    Wire.begin(3);
    Wire.onRequest(on_request);
}

void loop()
{
    if (digitalRead(PIN_DOUT))
        return;  /* no conversion ready */
    unsigned long stamp = micros();
    uint32_t bits = 0;
    for (uint8_t i = 0; i < 24; i++) {
        digitalWrite(PIN_SCLK, LOW);
        digitalWrite(PIN_SCLK, HIGH);
        bits = (bits << 1) | (uint8_t)digitalRead(PIN_DOUT);
    }
    uint16_t code = (uint16_t)(bits >> 8);
    bool error = bits & 0x20;
    if (!error) {
        noInterrupts();
        put16(12, code);
        put32(14, stamp);
        interrupts();
    }
}
