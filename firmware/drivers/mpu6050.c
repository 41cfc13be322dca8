/**
 * @file mpu6050.c
 * @brief MPU-6050 driver (see mpu6050.h). Register names and numbers are the RM's.
 */
#include "mpu6050.h"

/* ------------------------------------------------------------------ register map (RM rev 4.2) */

#define REG_SMPLRT_DIV 0x19u   /* sample rate divider */
#define REG_CONFIG 0x1Au       /* EXT_SYNC_SET[5:3], DLPF_CFG[2:0] */
#define REG_GYRO_CONFIG 0x1Bu  /* XG_ST, YG_ST, ZG_ST [7:5], FS_SEL[4:3] */
#define REG_ACCEL_CONFIG 0x1Cu /* XA_ST, YA_ST, ZA_ST [7:5], AFS_SEL[4:3] */
#define REG_INT_PIN_CFG 0x37u  /* INT_LEVEL, INT_OPEN, LATCH_INT_EN, INT_RD_CLEAR, FSYNC_INT_LEVEL,
                                  FSYNC_INT_EN, I2C_BYPASS_EN */
#define REG_INT_ENABLE 0x38u   /* MOT_EN, FIFO_OFLOW_EN, I2C_MST_INT_EN, DATA_RDY_EN */
#define REG_ACCEL_XOUT_H 0x3Bu /* first of the 14 data registers up to GYRO_ZOUT_L (0x48) */
#define REG_USER_CTRL 0x6Au    /* FIFO_EN, I2C_MST_EN, I2C_IF_DIS, FIFO_RESET, I2C_MST_RESET, SIG_COND_RESET */
#define REG_PWR_MGMT_1 0x6Bu   /* DEVICE_RESET, SLEEP, CYCLE, TEMP_DIS, CLKSEL[2:0] */
#define REG_WHO_AM_I 0x75u

#define GYRO_CONFIG_FS_SEL_SHIFT 3u
#define ACCEL_CONFIG_AFS_SEL_SHIFT 3u
#define INT_PIN_CFG_INT_RD_CLEAR 0x10u  /* status bits cleared by any read, not only of INT_STATUS */
#define INT_PIN_CFG_I2C_BYPASS_EN 0x02u /* auxiliary bus connected to the main bus (if I2C_MST_EN = 0) */
#define INT_ENABLE_DATA_RDY_EN 0x01u
#define USER_CTRL_I2C_MST_EN 0x20u
#define PWR_MGMT_1_DEVICE_RESET 0x80u
#define PWR_MGMT_1_CLKSEL_PLL_XGYRO 0x01u /* CLKSEL = 1; SLEEP, CYCLE, TEMP_DIS = 0 */

/* Bits each register defines: reserved bits are not compared when reading back. */
#define MASK_SMPLRT_DIV 0xFFu
#define MASK_CONFIG 0x3Fu
#define MASK_GYRO_CONFIG 0xF8u
#define MASK_ACCEL_CONFIG 0xF8u
#define MASK_INT_PIN_CFG 0xFEu
#define MASK_INT_ENABLE 0x59u
#define MASK_PWR_MGMT_1 0xEFu

/* ------------------------------------------------------------------ timing (PS rev 3.4) */

/** Start-up time for register read/write (PS electrical characteristics): the reset
 *  restarts the chip, so it gets the same time before it is asked anything. */
#define RESET_WAIT_MS 100u
/** If DEVICE_RESET has not cleared after RESET_WAIT_MS, look again this often, this many times. */
#define RESET_POLL_MS 10u
#define RESET_POLLS 10u
/** Gyroscope start-up time (PS gyroscope specifications, typical): samples before it are not settled. */
#define GYRO_STARTUP_MS 30u

/** Number of data registers ACCEL_XOUT_H .. GYRO_ZOUT_L. */
#define DATA_BYTES 14u

/* ------------------------------------------------------------------ sensitivities */

/** rad per degree, as the host computes it (numpy.deg2rad(1.0) is this same double). */
#define RAD_PER_DEG (3.141592653589793 / 180.0)
/** Standard gravity, m/s^2: the data sheet's "g" (host: imulink.core.counts.STANDARD_GRAVITY). */
#define STANDARD_GRAVITY 9.80665

/* Folded by the compiler (static initialisers are constant expressions): no floating
 * point at run time. The doubles are the host's SensorProfile.gyro_scale / acc_scale. */
static const imu_real_t gyro_scales[4] = {
    IMU_QCONST(RAD_PER_DEG / 131.0, 40), /* FS_SEL 0: 131 LSB/(deg/s) */
    IMU_QCONST(RAD_PER_DEG / 65.5, 40),  /* FS_SEL 1: 65.5 */
    IMU_QCONST(RAD_PER_DEG / 32.8, 40),  /* FS_SEL 2: 32.8 */
    IMU_QCONST(RAD_PER_DEG / 16.4, 40),  /* FS_SEL 3: 16.4 */
};
static const imu_real_t acc_scales[4] = {
    IMU_QCONST(STANDARD_GRAVITY / 16384.0, 32), /* AFS_SEL 0: 16384 LSB/g */
    IMU_QCONST(STANDARD_GRAVITY / 8192.0, 32),  /* AFS_SEL 1: 8192 */
    IMU_QCONST(STANDARD_GRAVITY / 4096.0, 32),  /* AFS_SEL 2: 4096 */
    IMU_QCONST(STANDARD_GRAVITY / 2048.0, 32),  /* AFS_SEL 3: 2048 */
};

/** Largest of gyroscope and accelerometer bandwidth of each DLPF_CFG, Hz (RM register 26). */
static const uint16_t dlpf_bandwidth_hz[MPU6050_DLPF_CFG_MAX + 1] = {260, 188, 98, 44, 21, 10, 5};

/* ------------------------------------------------------------------ configuration */

/** One register mpu6050_init() writes, and the bits that must read back. */
typedef struct {
    uint8_t reg;
    uint8_t value;
    uint8_t mask;
} reg_setting_t;

static sensor_status_t check_config(const mpu6050_config_t *config)
{
    if ((unsigned)config->gyro_range > (unsigned)MPU6050_GYRO_2000DPS) {
        return sensor_status_config(SENSOR_CHIP_MPU6050, REG_GYRO_CONFIG);
    }
    if ((unsigned)config->acc_range > (unsigned)MPU6050_ACC_16G) {
        return sensor_status_config(SENSOR_CHIP_MPU6050, REG_ACCEL_CONFIG);
    }
    if (config->dlpf_cfg > MPU6050_DLPF_CFG_MAX) {
        return sensor_status_config(SENSOR_CHIP_MPU6050, REG_CONFIG);
    }
    return sensor_status_ok(SENSOR_CHIP_MPU6050);
}

/** Reset and wait, bounded, until DEVICE_RESET reads 0 again (the chip clears it when done). */
static sensor_status_t reset(const sensor_device_t *dev)
{
    sensor_status_t s = sensor_write_reg(dev, REG_PWR_MGMT_1, PWR_MGMT_1_DEVICE_RESET);
    sensor_status_t last;
    uint8_t pwr = 0;
    unsigned polls;
    int read_once = 0;
    if (sensor_failed(&s)) {
        return s;
    }
    sensor_delay_ms(dev, RESET_WAIT_MS);
    last = s;
    for (polls = 0; polls < RESET_POLLS; ++polls) {
        if (polls > 0) {
            sensor_delay_ms(dev, RESET_POLL_MS);
        }
        last = sensor_read_regs(dev, REG_PWR_MGMT_1, &pwr, 1);
        /* A chip still busy with its reset may not answer: that is one more poll, not a failure. */
        if (sensor_failed(&last)) {
            continue;
        }
        read_once = 1;
        if ((pwr & PWR_MGMT_1_DEVICE_RESET) == 0) {
            return last;
        }
    }
    if (!read_once) {
        return last; /* never answered: the I2C error says more than "reset" */
    }
    s = sensor_status_ok(SENSOR_CHIP_MPU6050);
    s.result = SENSOR_ERR_RESET;
    s.reg = REG_PWR_MGMT_1;
    s.count = 1;
    s.got[0] = pwr;
    return s;
}

sensor_status_t mpu6050_init(mpu6050_t *mpu, const i2c_bus_t *bus, uint8_t address, const mpu6050_config_t *config)
{
    reg_setting_t settings[7];
    uint8_t who = 0;
    unsigned i;
    sensor_status_t s = check_config(config);

    mpu->dev.bus = bus;
    mpu->dev.address = address;
    mpu->dev.chip = SENSOR_CHIP_MPU6050;
    mpu->config = *config;
    /* Active high, push-pull, 50 us pulse (LATCH_INT_EN = 0), status cleared by any read:
     * the sample burst itself acknowledges the interrupt. Bypass off until asked for. */
    mpu->int_pin_cfg = INT_PIN_CFG_INT_RD_CLEAR;
    if (sensor_failed(&s)) {
        return s;
    }

    /* Identity before the first write: a different chip at this address gets nothing written. */
    s = sensor_read_regs(&mpu->dev, REG_WHO_AM_I, &who, 1);
    if (sensor_failed(&s)) {
        return s;
    }
    if (who != MPU6050_WHO_AM_I_VALUE) {
        return sensor_status_identity(SENSOR_CHIP_MPU6050, &who, 1);
    }

    /* A known state whatever ran before (a warm restart keeps the registers). */
    s = reset(&mpu->dev);
    if (sensor_failed(&s)) {
        return s;
    }

    /* After the reset the chip sleeps (PWR_MGMT_1 = 0x40); the first write wakes it. */
    settings[0].reg = REG_PWR_MGMT_1;
    settings[0].value = PWR_MGMT_1_CLKSEL_PLL_XGYRO;
    settings[0].mask = MASK_PWR_MGMT_1;
    settings[1].reg = REG_SMPLRT_DIV;
    settings[1].value = config->sample_rate_div;
    settings[1].mask = MASK_SMPLRT_DIV;
    settings[2].reg = REG_CONFIG; /* EXT_SYNC_SET = 0: FSYNC not sampled */
    settings[2].value = config->dlpf_cfg;
    settings[2].mask = MASK_CONFIG;
    settings[3].reg = REG_GYRO_CONFIG; /* self-test bits 0 */
    settings[3].value = (uint8_t)((unsigned)config->gyro_range << GYRO_CONFIG_FS_SEL_SHIFT);
    settings[3].mask = MASK_GYRO_CONFIG;
    settings[4].reg = REG_ACCEL_CONFIG;
    settings[4].value = (uint8_t)((unsigned)config->acc_range << ACCEL_CONFIG_AFS_SEL_SHIFT);
    settings[4].mask = MASK_ACCEL_CONFIG;
    settings[5].reg = REG_INT_PIN_CFG;
    settings[5].value = mpu->int_pin_cfg;
    settings[5].mask = MASK_INT_PIN_CFG;
    settings[6].reg = REG_INT_ENABLE;
    settings[6].value = config->data_ready_interrupt ? INT_ENABLE_DATA_RDY_EN : 0u;
    settings[6].mask = MASK_INT_ENABLE;

    for (i = 0; i < sizeof settings / sizeof settings[0]; ++i) {
        s = sensor_write_reg(&mpu->dev, settings[i].reg, settings[i].value);
        if (sensor_failed(&s)) {
            return s;
        }
    }
    /* Read back after all writes: a later write that disturbed an earlier register shows too. */
    for (i = 0; i < sizeof settings / sizeof settings[0]; ++i) {
        s = sensor_verify_reg(&mpu->dev, settings[i].reg, settings[i].value, settings[i].mask);
        if (sensor_failed(&s)) {
            return s;
        }
    }
    sensor_delay_ms(&mpu->dev, GYRO_STARTUP_MS);
    return s;
}

sensor_status_t mpu6050_set_bypass(mpu6050_t *mpu, int enable)
{
    uint8_t user_ctrl = 0;
    uint8_t int_pin_cfg;
    sensor_status_t s;

    if (enable) {
        /* Master off first: with I2C_MST_EN = 1 the bypass switch stays open (RM register 55). */
        s = sensor_read_regs(&mpu->dev, REG_USER_CTRL, &user_ctrl, 1);
        if (sensor_failed(&s)) {
            return s;
        }
        user_ctrl = (uint8_t)(user_ctrl & ~USER_CTRL_I2C_MST_EN);
        s = sensor_write_reg(&mpu->dev, REG_USER_CTRL, user_ctrl);
        if (sensor_failed(&s)) {
            return s;
        }
        int_pin_cfg = (uint8_t)(mpu->int_pin_cfg | INT_PIN_CFG_I2C_BYPASS_EN);
    } else {
        int_pin_cfg = (uint8_t)(mpu->int_pin_cfg & ~INT_PIN_CFG_I2C_BYPASS_EN);
    }
    s = sensor_write_reg(&mpu->dev, REG_INT_PIN_CFG, int_pin_cfg);
    if (sensor_failed(&s)) {
        return s;
    }
    mpu->int_pin_cfg = int_pin_cfg;
    s = sensor_verify_reg(&mpu->dev, REG_INT_PIN_CFG, int_pin_cfg, MASK_INT_PIN_CFG);
    if (sensor_failed(&s) || !enable) {
        return s;
    }
    return sensor_verify_reg(&mpu->dev, REG_USER_CTRL, user_ctrl, USER_CTRL_I2C_MST_EN);
}

sensor_status_t mpu6050_read(mpu6050_t *mpu, mpu6050_sample_t *sample)
{
    uint8_t raw[DATA_BYTES];
    unsigned i;
    sensor_status_t s = sensor_read_regs(&mpu->dev, REG_ACCEL_XOUT_H, raw, sizeof raw);
    if (sensor_failed(&s)) {
        return s;
    }
    /* Big-endian pairs: ACCEL_X/Y/Z, TEMP, GYRO_X/Y/Z. */
    for (i = 0; i < 3; ++i) {
        sample->acc[i] = sensor_be16(&raw[2 * i]);
        sample->gyr[i] = sensor_be16(&raw[8 + 2 * i]);
    }
    sample->temperature = sensor_be16(&raw[6]);
    return s;
}

uint8_t mpu6050_dlpf_for_rate(uint32_t sample_rate_hz)
{
    uint8_t cfg;
    for (cfg = 0; cfg <= MPU6050_DLPF_CFG_MAX; ++cfg) {
        /* bandwidth < rate / 2, in integers */
        if (2u * (uint32_t)dlpf_bandwidth_hz[cfg] < sample_rate_hz) {
            return cfg;
        }
    }
    return MPU6050_DLPF_CFG_MAX;
}

uint32_t mpu6050_sample_rate_mhz(const mpu6050_config_t *config)
{
    /* Gyroscope output rate: 8 kHz with the DLPF off (DLPF_CFG 0 or 7), 1 kHz otherwise. */
    uint32_t gyro_rate_mhz = (config->dlpf_cfg == 0 || config->dlpf_cfg == 7) ? 8000000u : 1000000u;
    return gyro_rate_mhz / (1u + config->sample_rate_div);
}

imu_real_t mpu6050_gyro_scale(mpu6050_gyro_range_t range)
{
    return (unsigned)range < 4u ? gyro_scales[range] : 0;
}

imu_real_t mpu6050_acc_scale(mpu6050_acc_range_t range)
{
    return (unsigned)range < 4u ? acc_scales[range] : 0;
}
