/**
 * @file sensor_regs.c
 * @brief Register transfers (see sensor_regs.h).
 */
#include "sensor_regs.h"

sensor_status_t sensor_write_reg(const sensor_device_t *dev, uint8_t reg, uint8_t value)
{
    uint8_t bytes[2];
    i2c_status_t rc;
    bytes[0] = reg;
    bytes[1] = value;
    rc = dev->bus->write(dev->bus->context, dev->address, bytes, sizeof bytes);
    return rc == I2C_OK ? sensor_status_ok(dev->chip) : sensor_status_i2c(dev->chip, rc, reg);
}

sensor_status_t sensor_read_regs(const sensor_device_t *dev, uint8_t first_reg, uint8_t *data, size_t len)
{
    i2c_status_t rc = dev->bus->write_read(dev->bus->context, dev->address, &first_reg, 1, data, len);
    return rc == I2C_OK ? sensor_status_ok(dev->chip) : sensor_status_i2c(dev->chip, rc, first_reg);
}

sensor_status_t sensor_verify_reg(const sensor_device_t *dev, uint8_t reg, uint8_t wrote, uint8_t mask)
{
    uint8_t got = 0;
    sensor_status_t s = sensor_read_regs(dev, reg, &got, 1);
    if (sensor_failed(&s)) {
        return s;
    }
    /* Only the register's defined bits count: reserved bits may read anything. */
    if ((uint8_t)(got & mask) != (uint8_t)(wrote & mask)) {
        return sensor_status_readback(dev->chip, reg, wrote, got);
    }
    return s;
}

void sensor_delay_ms(const sensor_device_t *dev, uint32_t ms)
{
    dev->bus->delay_ms(dev->bus->context, ms);
}

int16_t sensor_be16(const uint8_t *msb_first)
{
    int32_t v = (int32_t)(((uint32_t)msb_first[0] << 8) | msb_first[1]);
    /* Two's complement by arithmetic: converting 0x8000..0xFFFF to int16_t directly
     * would be implementation-defined. */
    if (v >= 32768) {
        v -= 65536;
    }
    return (int16_t)v;
}
