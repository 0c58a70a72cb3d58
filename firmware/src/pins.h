/* Nano pin map (thesis rig wiring). Port/bit pairs are used directly in the ISRs and
 * the ADC bit-bang because digitalWrite()/digitalRead() cost ~50 cycles each. */
#ifndef DYNO_PINS_H
#define DYNO_PINS_H

/* Hall sensors: D2 = PD2 = INT0 (primary, engine side), D3 = PD3 = INT1 (secondary). */
#define PIN_HALL_PRIMARY_BIT 2
#define PIN_HALL_SECONDARY_BIT 3
/* AD7171: D4 = PD4 SCLK (output, idles high), D5 = PD5 DOUT/RDY (input). */
#define PIN_ADC_SCLK_BIT 4
#define PIN_ADC_DOUT_BIT 5
/* The input torque AD7171 (issue 27): D8 = PB0 DOUT2/RDY2 (PCINT0; also ICP1), D9 = PB1 SCLK2.
 * Its own SCLK: the AD7171 has no chip select, two cannot share a clock line. */
#define PIN_IN_DOUT_BIT 0
#define PIN_IN_SCLK_BIT 1
/* The run-enable output (issue 37): D7 = PD7, output low from the start of setup(); an external
 * pull-down holds the driver off while the pin is high-Z (reset, bootloader, unpowered). Static high while
 * on (watchdog build); a pulse train, toggled every main-loop pass, in the old-bootloader build (a charge
 * pump: a hung loop stops it). */
#define PIN_RUN_BIT 7
/* I2C: A4 = SDA, A5 = SCL (TWI hardware). USB serial: D0/D1 via the CH340/FT232. */

#endif
