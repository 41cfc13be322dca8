/**
 * @file ms5611.h
 * @brief MEAS (TE Connectivity) MS5611-01BA barometer over the portable I2C interface.
 *
 * Follows the data sheet "MS5611-01BA03 Barometric Pressure Sensor, with stainless steel
 * cap" ("DS") and its application note AN520 for the PROM's CRC-4; the names D1, D2,
 * C1..C6, dT, TEMP, OFF, SENS, P are the data sheet's.
 *
 * The chip has no registers, only commands: RESET (0x1E), CONVERT D1 (pressure, 0x40 +
 * 2 OSR index) and D2 (temperature, 0x50 + 2 OSR index), ADC READ (0x00: the last
 * conversion, 24 bits, big-endian; 0 when no conversion ran since the last read) and
 * PROM READ (0xA0 + 2 k: word k of 8, big-endian; words 1..6 are C1..C6, the low four
 * bits of word 7 the CRC-4 of all eight).
 *
 * ms5611_init() resets the chip, waits for it to reload its PROM (2.8 ms, DS), reads the
 * eight words and checks their CRC-4 (the chip has no identification register: a valid
 * CRC is what says an MS5611 answered). ms5611_poll() is a state machine that never
 * waits: each call does at most one step (start the D1 conversion; once its conversion
 * time has passed, read it and start D2; once D2's has passed, read it and compensate),
 * so a board calls it from its sample loop and a conversion (up to 9.04 ms at OSR 4096)
 * never holds the loop up. ms5611_compensate() is the data sheet's integer algorithm,
 * first and second order, bit for bit (its worked example is a test).
 *
 * No dynamic memory, integer only, bounded time.
 */
#ifndef MS5611_H
#define MS5611_H

#include <stdint.h>

#include "i2c.h"
#include "sensor_status.h"

/** 7-bit I2C address with CSB low, the GY-86 barometer's (0x76 with CSB high). */
#define MS5611_ADDRESS 0x77u

/** Oversampling ratio of a conversion: resolution against conversion time (DS, table of
 *  ADC conversion times: 0.60, 1.17, 2.28, 4.54, 9.04 ms at most). */
typedef enum {
    MS5611_OSR_256 = 0,
    MS5611_OSR_512 = 1,
    MS5611_OSR_1024 = 2,
    MS5611_OSR_2048 = 3,
    MS5611_OSR_4096 = 4,
} ms5611_osr_t;

/** Commands (DS, command table). */
#define MS5611_CMD_RESET 0x1Eu
#define MS5611_CMD_CONVERT_D1 0x40u /**< + 2 * ms5611_osr_t */
#define MS5611_CMD_CONVERT_D2 0x50u /**< + 2 * ms5611_osr_t */
#define MS5611_CMD_ADC_READ 0x00u
#define MS5611_CMD_PROM_READ 0xA0u /**< + 2 * word index (0..7) */

/** One compensated measurement. */
typedef struct {
    int32_t pressure_pa;      /**< P, Pa (the data sheet's 0.01 mbar), 1000..120000 in the specified range */
    int32_t temperature_cdeg; /**< TEMP, 0.01 degC, -4000..8500 in the specified range */
    uint32_t d1;              /**< the raw pressure conversion, 24 bits */
    uint32_t d2;              /**< the raw temperature conversion, 24 bits */
} ms5611_reading_t;

/** A chip on a bus. All members are private. */
typedef struct {
    const i2c_bus_t *bus;
    uint8_t address;
    ms5611_osr_t osr;
    uint16_t prom[8];    /**< the PROM words; C1..C6 at 1..6 */
    uint8_t phase;       /**< what runs: nothing, D1 or D2 (ms5611.c) */
    uint32_t started_us; /**< board time the running conversion was started, us */
    uint32_t d1;         /**< D1 while D2 converts */
} ms5611_t;

/**
 * @brief Reset the chip, read its PROM and check the CRC-4.
 * @return SENSOR_OK; SENSOR_ERR_I2C (`reg` the command); SENSOR_ERR_PROM_CRC (a CRC mismatch,
 *         or C1..C6 all zero, which a valid CRC does not rule out); SENSOR_ERR_CONFIG for an
 *         oversampling ratio the chip does not have.
 */
sensor_status_t ms5611_init(ms5611_t *dev, const i2c_bus_t *bus, uint8_t address, ms5611_osr_t osr);

/**
 * @brief One step of the measurement cycle, never waiting.
 * @param now_us board time, us (wrapping; differences below 2^31 us are taken right)
 * @param out    set when a measurement completed (*ready = 1)
 * @param ready  1 when `out` holds a new measurement, else 0
 * @return SENSOR_OK; SENSOR_ERR_I2C or SENSOR_ERR_ADC (the cycle starts again at the next call).
 */
sensor_status_t ms5611_poll(ms5611_t *dev, uint32_t now_us, ms5611_reading_t *out, int *ready);

/** @brief Conversion time the driver allows at `osr` (the data sheet's maximum), us; 0 for an unknown ratio. */
uint32_t ms5611_conversion_us(ms5611_osr_t osr);

/** @brief The CRC-4 of eight PROM words (AN520: the low four bits of word 7 are not part of it). */
uint8_t ms5611_prom_crc(const uint16_t prom[8]);

/**
 * @brief The data sheet's compensation of D1 and D2 with the PROM's C1..C6, first and
 *        second order (below 20 degC and below -15 degC), in its integer arithmetic: every
 *        "/ 2^n" is C's division (truncation toward zero) and every intermediate int64.
 *        Bounds for any 16-bit coefficients and 24-bit conversions: |dT| < 2^24,
 *        |TEMP - 2000| < 2^17, |OFF|, |SENS| < 2^39 (second order included),
 *        |D1 SENS| < 2^63, |P| < 2^27 and |T2| < 2^17: nothing overflows, and both
 *        results fit int32.
 */
void ms5611_compensate(const uint16_t prom[8], uint32_t d1, uint32_t d2, ms5611_reading_t *out);

#endif /* MS5611_H */
