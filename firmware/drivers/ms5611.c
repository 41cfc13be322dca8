/**
 * @file ms5611.c
 * @brief MS5611 barometer driver (see ms5611.h).
 */
#include "ms5611.h"

/** What ms5611_t.phase says runs. */
enum { PHASE_IDLE = 0, PHASE_D1 = 1, PHASE_D2 = 2 };

/** Maximum conversion times by OSR index, us (DS, ADC conversion time). */
static const uint32_t conversion_us[5] = {600u, 1170u, 2280u, 4540u, 9040u};

/** Time the chip takes to reload its PROM after RESET, ms (DS: 2.8 ms), rounded up. */
#define RESET_MS 3u

uint32_t ms5611_conversion_us(ms5611_osr_t osr)
{
    return (unsigned)osr < 5u ? conversion_us[osr] : 0u;
}

uint8_t ms5611_prom_crc(const uint16_t prom[8])
{
    uint16_t remainder = 0;
    int byte, bit;
    /* AN520: the sixteen bytes of the eight words, most significant first, through the
     * polynomial x^4 + x^1 + x^0 (0x3 in the top nibble: 0x3000), with word 7's own CRC
     * nibble and the byte after it taken as zero. */
    for (byte = 0; byte < 16; ++byte) {
        uint16_t word = prom[byte >> 1];
        if (byte >= 14) {
            word &= 0xFF00u; /* word 7 without its CRC byte */
        }
        remainder ^= (byte & 1) != 0 ? (uint16_t)(word & 0x00FFu) : (uint16_t)(word >> 8);
        for (bit = 0; bit < 8; ++bit) {
            remainder = (remainder & 0x8000u) != 0 ? (uint16_t)((remainder << 1) ^ 0x3000u)
                                                   : (uint16_t)(remainder << 1);
        }
    }
    return (uint8_t)((remainder >> 12) & 0x0Fu);
}

void ms5611_compensate(const uint16_t prom[8], uint32_t d1, uint32_t d2, ms5611_reading_t *out)
{
    const int64_t c1 = prom[1], c2 = prom[2], c3 = prom[3], c4 = prom[4], c5 = prom[5], c6 = prom[6];
    /* First order (DS, "calculate temperature" and "calculate temperature compensated pressure"). */
    const int64_t dt = (int64_t)d2 - c5 * 256;                /* dT = D2 - C5 2^8 */
    int64_t temp = 2000 + dt * c6 / 8388608;                  /* TEMP = 2000 + dT C6 / 2^23 */
    int64_t off = c2 * 65536 + c4 * dt / 128;                 /* OFF = C2 2^16 + C4 dT / 2^7 */
    int64_t sens = c1 * 32768 + c3 * dt / 256;                /* SENS = C1 2^15 + C3 dT / 2^8 */
    /* Second order (DS, "second order temperature compensation"): below 20 degC, more below -15 degC. */
    if (temp < 2000) {
        const int64_t t2 = dt * dt / 2147483648LL;            /* T2 = dT^2 / 2^31 */
        const int64_t below = (temp - 2000) * (temp - 2000);
        int64_t off2 = 5 * below / 2;                         /* OFF2 = 5 (TEMP - 2000)^2 / 2^1 */
        int64_t sens2 = 5 * below / 4;                        /* SENS2 = 5 (TEMP - 2000)^2 / 2^2 */
        if (temp < -1500) {
            const int64_t cold = (temp + 1500) * (temp + 1500);
            off2 += 7 * cold;                                 /* OFF2 += 7 (TEMP + 1500)^2 */
            sens2 += 11 * cold / 2;                           /* SENS2 += 11 (TEMP + 1500)^2 / 2^1 */
        }
        temp -= t2;
        off -= off2;
        sens -= sens2;
    }
    out->pressure_pa = (int32_t)(((int64_t)d1 * sens / 2097152 - off) / 32768); /* P = (D1 SENS / 2^21 - OFF) / 2^15 */
    out->temperature_cdeg = (int32_t)temp;
    out->d1 = d1;
    out->d2 = d2;
}

static sensor_status_t command(const ms5611_t *dev, uint8_t cmd)
{
    const i2c_status_t r = dev->bus->write(dev->bus->context, dev->address, &cmd, 1);
    return r == I2C_OK ? sensor_status_ok(SENSOR_CHIP_MS5611) : sensor_status_i2c(SENSOR_CHIP_MS5611, r, cmd);
}

sensor_status_t ms5611_init(ms5611_t *dev, const i2c_bus_t *bus, uint8_t address, ms5611_osr_t osr)
{
    sensor_status_t s;
    uint8_t k, computed;
    dev->bus = bus;
    dev->address = address;
    dev->osr = osr;
    dev->phase = PHASE_IDLE;
    dev->started_us = 0;
    dev->d1 = 0;
    for (k = 0; k < 8; ++k) {
        dev->prom[k] = 0;
    }
    if (ms5611_conversion_us(osr) == 0) {
        return sensor_status_config(SENSOR_CHIP_MS5611, MS5611_CMD_CONVERT_D1);
    }
    s = command(dev, MS5611_CMD_RESET);
    if (sensor_failed(&s)) {
        return s;
    }
    bus->delay_ms(bus->context, RESET_MS);
    for (k = 0; k < 8; ++k) {
        const uint8_t cmd = (uint8_t)(MS5611_CMD_PROM_READ + 2u * k);
        uint8_t word[2];
        const i2c_status_t r = bus->write_read(bus->context, address, &cmd, 1, word, 2);
        if (r != I2C_OK) {
            return sensor_status_i2c(SENSOR_CHIP_MS5611, r, cmd);
        }
        dev->prom[k] = (uint16_t)((word[0] << 8) | word[1]);
    }
    computed = ms5611_prom_crc(dev->prom);
    if (computed != (dev->prom[7] & 0x0Fu) || (dev->prom[1] | dev->prom[2] | dev->prom[3] | dev->prom[4] |
                                              dev->prom[5] | dev->prom[6]) == 0) {
        /* (eight zero words have a valid CRC: a PROM read before the chip reloaded it) */
        return sensor_status_prom_crc(SENSOR_CHIP_MS5611, computed, (uint8_t)(dev->prom[7] & 0x0Fu));
    }
    return sensor_status_ok(SENSOR_CHIP_MS5611);
}

/** Read the finished conversion started by command `started`; 0 from the chip is no result. */
static sensor_status_t read_adc(const ms5611_t *dev, uint8_t started, uint32_t *value)
{
    const uint8_t cmd = MS5611_CMD_ADC_READ;
    uint8_t bytes[3];
    const i2c_status_t r = dev->bus->write_read(dev->bus->context, dev->address, &cmd, 1, bytes, 3);
    if (r != I2C_OK) {
        return sensor_status_i2c(SENSOR_CHIP_MS5611, r, cmd);
    }
    *value = ((uint32_t)bytes[0] << 16) | ((uint32_t)bytes[1] << 8) | bytes[2];
    return *value != 0 ? sensor_status_ok(SENSOR_CHIP_MS5611) : sensor_status_adc(SENSOR_CHIP_MS5611, started);
}

sensor_status_t ms5611_poll(ms5611_t *dev, uint32_t now_us, ms5611_reading_t *out, int *ready)
{
    const uint8_t step = (uint8_t)(2u * (unsigned)dev->osr);
    sensor_status_t s = sensor_status_ok(SENSOR_CHIP_MS5611);
    uint32_t d2;
    *ready = 0;
    if (dev->phase != PHASE_IDLE && now_us - dev->started_us < conversion_us[dev->osr]) {
        return s; /* converting */
    }
    switch (dev->phase) {
    case PHASE_IDLE:
        s = command(dev, (uint8_t)(MS5611_CMD_CONVERT_D1 + step));
        dev->phase = sensor_failed(&s) ? PHASE_IDLE : PHASE_D1;
        break;
    case PHASE_D1:
        s = read_adc(dev, (uint8_t)(MS5611_CMD_CONVERT_D1 + step), &dev->d1);
        if (!sensor_failed(&s)) {
            s = command(dev, (uint8_t)(MS5611_CMD_CONVERT_D2 + step));
        }
        dev->phase = sensor_failed(&s) ? PHASE_IDLE : PHASE_D2;
        break;
    default: /* PHASE_D2 */
        s = read_adc(dev, (uint8_t)(MS5611_CMD_CONVERT_D2 + step), &d2);
        dev->phase = PHASE_IDLE;
        if (!sensor_failed(&s)) {
            ms5611_compensate(dev->prom, dev->d1, d2, out);
            *ready = 1;
        }
        break;
    }
    dev->started_us = now_us;
    return s;
}
