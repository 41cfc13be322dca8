/**
 * @file hmc5883l.c
 * @brief HMC5883L driver (see hmc5883l.h). Register names are the data sheet's (Rev E).
 */
#include "hmc5883l.h"

/* ------------------------------------------------------------------ register map */

#define REG_CONFIG_A 0x00u  /* CRA7 (must be 0), MA1..0, DO2..0, MS1..0 */
#define REG_CONFIG_B 0x01u  /* GN2..0, CRB4..0 (must be 0) */
#define REG_MODE 0x02u      /* MR7..2 (written 0), MD1..0 operating mode */
#define REG_DATA_X_MSB 0x03u /* data: X MSB, X LSB, Z MSB, Z LSB, Y MSB, Y LSB (0x03..0x08) */
#define REG_IDENT_A 0x0Au   /* 'H'; B (0x0B) '4', C (0x0C) '3' */

#define CONFIG_A_MA_SHIFT 5u
#define CONFIG_A_DO_SHIFT 2u
#define CONFIG_B_GN_SHIFT 5u
#define MODE_CONTINUOUS 0x00u

/* Bits read back: all of Configuration A and B (their must-be-zero bits included: a chip
 * holding a 1 there does not measure correctly), the operating-mode bits MD1..0 of the
 * Mode register (its upper bits are not part of the configuration). */
#define MASK_CONFIG_A 0xFFu
#define MASK_CONFIG_B 0xFFu
#define MASK_MODE 0x03u

/** Wait for the first measurement after entering continuous mode (DS operational example, step 4). */
#define FIRST_MEASUREMENT_MS 6u

/** Sensitivity of each gain GN, LSB/gauss (DS, Configuration Register B gain settings). */
static const uint16_t lsb_per_gauss[8] = {1370, 1090, 820, 660, 440, 390, 330, 230};

/* uT per LSB = 100 uT/gauss / (LSB/gauss), the host's SensorProfile.mag_scale, folded at
 * compile time (static initialisers are constant expressions: no run-time floating point). */
static const imu_real_t mag_scales[8] = {
    IMU_QCONST(100.0 / 1370.0, 24), IMU_QCONST(100.0 / 1090.0, 24), IMU_QCONST(100.0 / 820.0, 24),
    IMU_QCONST(100.0 / 660.0, 24),  IMU_QCONST(100.0 / 440.0, 24),  IMU_QCONST(100.0 / 390.0, 24),
    IMU_QCONST(100.0 / 330.0, 24),  IMU_QCONST(100.0 / 230.0, 24),
};

static sensor_status_t check_config(const hmc5883l_config_t *config)
{
    if ((unsigned)config->averaging > (unsigned)HMC5883L_AVERAGE_8 ||
        (unsigned)config->rate > (unsigned)HMC5883L_RATE_75HZ ||
        (unsigned)config->bias > (unsigned)HMC5883L_BIAS_NEGATIVE) {
        return sensor_status_config(SENSOR_CHIP_HMC5883L, REG_CONFIG_A);
    }
    if ((unsigned)config->gain > (unsigned)HMC5883L_GAIN_230) {
        return sensor_status_config(SENSOR_CHIP_HMC5883L, REG_CONFIG_B);
    }
    return sensor_status_ok(SENSOR_CHIP_HMC5883L);
}

sensor_status_t hmc5883l_init(hmc5883l_t *mag, const i2c_bus_t *bus, uint8_t address, const hmc5883l_config_t *config)
{
    static const uint8_t identity[3] = {'H', '4', '3'};
    uint8_t id[3] = {0, 0, 0};
    uint8_t wrote[3];
    uint8_t got[3] = {0, 0, 0};
    uint8_t discard[6];
    static const uint8_t masks[3] = {MASK_CONFIG_A, MASK_CONFIG_B, MASK_MODE};
    uint8_t i;
    sensor_status_t s = check_config(config);

    mag->dev.bus = bus;
    mag->dev.address = address;
    mag->dev.chip = SENSOR_CHIP_HMC5883L;
    mag->config = *config;
    if (sensor_failed(&s)) {
        return s;
    }

    /* Identity first: nothing is written to a chip that is not an HMC5883L. The pointer
     * auto-increments 10 -> 11 -> 12, so one burst reads all three. */
    s = sensor_read_regs(&mag->dev, REG_IDENT_A, id, sizeof id);
    if (sensor_failed(&s)) {
        return s;
    }
    if (id[0] != identity[0] || id[1] != identity[1] || id[2] != identity[2]) {
        return sensor_status_identity(SENSOR_CHIP_HMC5883L, id, 3);
    }

    wrote[0] = (uint8_t)(((unsigned)config->averaging << CONFIG_A_MA_SHIFT) |
                         ((unsigned)config->rate << CONFIG_A_DO_SHIFT) | (unsigned)config->bias);
    wrote[1] = (uint8_t)((unsigned)config->gain << CONFIG_B_GN_SHIFT);
    wrote[2] = MODE_CONTINUOUS;
    /* One register per transfer, as the data sheet's examples do: its pointer rule is
     * only described for reads. The mode comes last: measuring starts with the gain set. */
    for (i = 0; i < 3; ++i) {
        s = sensor_write_reg(&mag->dev, (uint8_t)(REG_CONFIG_A + i), wrote[i]);
        if (sensor_failed(&s)) {
            return s;
        }
    }
    /* Read back 0, 1, 2 in one burst (the pointer increments through them). */
    s = sensor_read_regs(&mag->dev, REG_CONFIG_A, got, sizeof got);
    if (sensor_failed(&s)) {
        return s;
    }
    for (i = 0; i < 3; ++i) {
        if ((uint8_t)(got[i] & masks[i]) != (uint8_t)(wrote[i] & masks[i])) {
            return sensor_status_readback(SENSOR_CHIP_HMC5883L, (uint8_t)(REG_CONFIG_A + i), wrote[i], got[i]);
        }
    }
    /* Reading the Mode register has set the data lock (DS, Status register LOCK): no new
     * measurement is stored until all six data registers are read. Read them once now,
     * so the first hmc5883l_read() gets the first measurement, not the power-on data. */
    s = sensor_read_regs(&mag->dev, REG_DATA_X_MSB, discard, sizeof discard);
    if (sensor_failed(&s)) {
        return s;
    }
    sensor_delay_ms(&mag->dev, FIRST_MEASUREMENT_MS);
    return s;
}

sensor_status_t hmc5883l_read(hmc5883l_t *mag, int16_t xyz[3])
{
    uint8_t raw[6];
    int16_t x, y, z;
    unsigned channels = 0;
    sensor_status_t s = sensor_read_regs(&mag->dev, REG_DATA_X_MSB, raw, sizeof raw);
    if (sensor_failed(&s)) {
        return s;
    }
    /* Register order X, Z, Y (DS register list): reading all six also releases the
     * chip's data lock (Status register LOCK) so the next measurement can be stored. */
    x = sensor_be16(&raw[0]);
    z = sensor_be16(&raw[2]);
    y = sensor_be16(&raw[4]);
    xyz[0] = x;
    xyz[1] = y;
    xyz[2] = z;
    if (x == HMC5883L_OVERFLOW) {
        channels |= SENSOR_CHANNEL_X;
    }
    if (y == HMC5883L_OVERFLOW) {
        channels |= SENSOR_CHANNEL_Y;
    }
    if (z == HMC5883L_OVERFLOW) {
        channels |= SENSOR_CHANNEL_Z;
    }
    if (channels != 0) {
        s.result = SENSOR_MAG_OVERFLOW;
        s.channels = (uint8_t)channels;
    }
    return s;
}

uint16_t hmc5883l_lsb_per_gauss(hmc5883l_gain_t gain)
{
    return (unsigned)gain < 8u ? lsb_per_gauss[gain] : 0u;
}

imu_real_t hmc5883l_mag_scale(hmc5883l_gain_t gain)
{
    return (unsigned)gain < 8u ? mag_scales[gain] : 0;
}
