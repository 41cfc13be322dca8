/**
 * @file sensor_status.c
 * @brief Status constructors and texts (see sensor_status.h).
 *
 * The text is assembled by hand (no printf: the drivers build without a C library).
 */
#include "sensor_status.h"

/** Name of a chip and what its identification registers should hold, as a LOG line shows it. */
typedef struct {
    const char *name;
    const char *expected_identity;
} chip_text_t;

static chip_text_t chip_text(sensor_chip_t chip)
{
    chip_text_t t = {"sensor", "?"};
    switch (chip) {
    case SENSOR_CHIP_MPU6050:
        t.name = "MPU6050";
        t.expected_identity = "0x68"; /* WHO_AM_I */
        break;
    case SENSOR_CHIP_HMC5883L:
        t.name = "HMC5883L";
        t.expected_identity = "H43"; /* identification registers A, B, C */
        break;
    case SENSOR_CHIP_MS5611:
        t.name = "MS5611";
        t.expected_identity = "a PROM with a valid CRC-4"; /* it has no identification register */
        break;
    }
    return t;
}

static sensor_status_t blank(sensor_chip_t chip, sensor_result_t result)
{
    sensor_status_t s;
    s.result = result;
    s.chip = chip;
    s.i2c = I2C_OK;
    s.reg = 0;
    s.wrote = 0;
    s.count = 0;
    s.got[0] = s.got[1] = s.got[2] = 0;
    s.channels = 0;
    return s;
}

sensor_status_t sensor_status_ok(sensor_chip_t chip)
{
    return blank(chip, SENSOR_OK);
}

sensor_status_t sensor_status_i2c(sensor_chip_t chip, i2c_status_t i2c, uint8_t reg)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_I2C);
    s.i2c = i2c;
    s.reg = reg;
    return s;
}

sensor_status_t sensor_status_identity(sensor_chip_t chip, const uint8_t *got, uint8_t count)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_IDENTITY);
    uint8_t i;
    s.count = count > 3 ? 3 : count;
    for (i = 0; i < s.count; ++i) {
        s.got[i] = got[i];
    }
    return s;
}

sensor_status_t sensor_status_readback(sensor_chip_t chip, uint8_t reg, uint8_t wrote, uint8_t got)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_READBACK);
    s.reg = reg;
    s.wrote = wrote;
    s.count = 1;
    s.got[0] = got;
    return s;
}

sensor_status_t sensor_status_config(sensor_chip_t chip, uint8_t reg)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_CONFIG);
    s.reg = reg;
    return s;
}

sensor_status_t sensor_status_prom_crc(sensor_chip_t chip, uint8_t computed, uint8_t stored)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_PROM_CRC);
    s.count = 2;
    s.got[0] = computed;
    s.got[1] = stored;
    return s;
}

sensor_status_t sensor_status_adc(sensor_chip_t chip, uint8_t command)
{
    sensor_status_t s = blank(chip, SENSOR_ERR_ADC);
    s.reg = command;
    return s;
}

/* ------------------------------------------------------------------ text assembly */

/** A bounded string being written: never overruns, always NUL-terminated. */
typedef struct {
    char *buf;
    size_t cap;
    size_t len;
} text_t;

static void put(text_t *t, const char *s)
{
    while (*s != '\0' && t->len + 1 < t->cap) {
        t->buf[t->len++] = *s++;
    }
    t->buf[t->len] = '\0';
}

static void put_hex8(text_t *t, uint8_t v)
{
    static const char digits[] = "0123456789ABCDEF";
    char hex[5];
    hex[0] = '0';
    hex[1] = 'x';
    hex[2] = digits[v >> 4];
    hex[3] = digits[v & 0x0Fu];
    hex[4] = '\0';
    put(t, hex);
}

const char *sensor_status_text(const sensor_status_t *status, char *buf, size_t cap)
{
    text_t t;
    chip_text_t chip;
    uint8_t i;
    if (buf == NULL || cap == 0) {
        return "";
    }
    t.buf = buf;
    t.cap = cap;
    t.len = 0;
    buf[0] = '\0';
    chip = chip_text(status->chip);
    put(&t, chip.name);
    put(&t, ": ");
    switch (status->result) {
    case SENSOR_OK:
        put(&t, "OK");
        break;
    case SENSOR_MAG_OVERFLOW:
        put(&t, "overflow on");
        if (status->channels & SENSOR_CHANNEL_X) {
            put(&t, " x");
        }
        if (status->channels & SENSOR_CHANNEL_Y) {
            put(&t, " y");
        }
        if (status->channels & SENSOR_CHANNEL_Z) {
            put(&t, " z");
        }
        break;
    case SENSOR_ERR_I2C:
        put(&t, i2c_status_text(status->i2c));
        /* Without an address acknowledge no register was reached: naming one would mislead. */
        if (status->i2c != I2C_ERR_NACK_ADDRESS) {
            put(&t, " at register ");
            put_hex8(&t, status->reg);
        }
        break;
    case SENSOR_ERR_IDENTITY:
        put(&t, "wrong identity");
        for (i = 0; i < status->count && i < 3; ++i) {
            put(&t, " ");
            put_hex8(&t, status->got[i]);
        }
        put(&t, " (expected ");
        put(&t, chip.expected_identity);
        put(&t, ")");
        break;
    case SENSOR_ERR_READBACK:
        put(&t, "register ");
        put_hex8(&t, status->reg);
        put(&t, " reads ");
        put_hex8(&t, status->got[0]);
        put(&t, " after writing ");
        put_hex8(&t, status->wrote);
        break;
    case SENSOR_ERR_RESET:
        put(&t, "reset did not complete");
        if (status->count > 0) {
            put(&t, " (register ");
            put_hex8(&t, status->reg);
            put(&t, " reads ");
            put_hex8(&t, status->got[0]);
            put(&t, ")");
        }
        break;
    case SENSOR_ERR_CONFIG:
        put(&t, "configuration not supported (register ");
        put_hex8(&t, status->reg);
        put(&t, ")");
        break;
    case SENSOR_ERR_PROM_CRC:
        if (status->got[0] == status->got[1]) {
            put(&t, "PROM holds no calibration (coefficients all zero)");
            break;
        }
        put(&t, "PROM CRC-4 is ");
        put_hex8(&t, status->got[1]);
        put(&t, ", its contents give ");
        put_hex8(&t, status->got[0]);
        break;
    case SENSOR_ERR_ADC:
        put(&t, "ADC read 0 after command ");
        put_hex8(&t, status->reg);
        put(&t, " (no conversion result)");
        break;
    default:
        put(&t, "unknown status");
        break;
    }
    return buf;
}
