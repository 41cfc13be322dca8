/**
 * @file gy86.c
 * @brief GY-86 module (see gy86.h): bring-up order, sample assembly, magnetometer axes.
 */
#include "gy86.h"

const gy86_config_t gy86_default_config = {
    .mpu = {.gyro_range = MPU6050_GYRO_2000DPS,
            .acc_range = MPU6050_ACC_8G,
            .dlpf_cfg = 3u,         /* 42/44 Hz: mpu6050_dlpf_for_rate(100) */
            .sample_rate_div = 9u,  /* 1 kHz / (1 + 9) = 100 Hz */
            .data_ready_interrupt = 1u},
    .mag = {.averaging = HMC5883L_AVERAGE_1,
            .rate = HMC5883L_RATE_75HZ,
            .bias = HMC5883L_BIAS_NONE,
            .gain = HMC5883L_GAIN_1090},
};

/**
 * Magnetometer axes on the GY-86 PCB. Row i: core axis i (= MPU6050 axis i) is
 * `sign` times HMC5883L axis `from`. The mapping is the identity: the HMC5883L's X, Y,
 * Z are parallel to the MPU6050's x, y, z.
 *
 * How the mapping was established, and how to check it on a bench: docs/firmware.md,
 * "The GY-86's magnetometer axes".
 */
typedef struct {
    uint8_t from; /**< HMC5883L axis: 0 X, 1 Y, 2 Z */
    int8_t sign;  /**< +1 or -1 */
} axis_map_t;

static const axis_map_t mag_axes[3] = {
    {0, +1}, /* core x <- HMC5883L X */
    {1, +1}, /* core y <- HMC5883L Y */
    {2, +1}, /* core z <- HMC5883L Z */
};

sensor_status_t gy86_init(gy86_t *gy, const i2c_bus_t *bus, const gy86_config_t *config)
{
    sensor_status_t s = mpu6050_init(&gy->mpu, bus, GY86_MPU6050_ADDRESS, &config->mpu);
    if (sensor_failed(&s)) {
        return s;
    }
    /* The HMC5883L hangs on the MPU6050's auxiliary bus: unreachable until the bypass is on. */
    s = mpu6050_set_bypass(&gy->mpu, 1);
    if (sensor_failed(&s)) {
        return s;
    }
    return hmc5883l_init(&gy->mag, bus, GY86_HMC5883L_ADDRESS, &config->mag);
}

sensor_status_t gy86_read(gy86_t *gy, imu_raw_sample_t *raw, int16_t *temperature)
{
    mpu6050_sample_t motion;
    int16_t field[3];
    unsigned i;
    sensor_status_t s = mpu6050_read(&gy->mpu, &motion);
    if (sensor_failed(&s)) {
        return s;
    }
    s = hmc5883l_read(&gy->mag, field);
    if (sensor_failed(&s)) {
        return s; /* nothing delivered: a sample without its field would mix two instants */
    }
    for (i = 0; i < 3; ++i) {
        int16_t v = field[mag_axes[i].from];
        raw->gyr[i] = motion.gyr[i];
        raw->acc[i] = motion.acc[i];
        /* The overflow marker stays the marker whatever the sign (it is beyond -2048 either way). */
        raw->mag[i] = (mag_axes[i].sign < 0 && v != HMC5883L_OVERFLOW) ? (int16_t)-v : v;
    }
    if (temperature != NULL) {
        *temperature = motion.temperature;
    }
    return s;
}

void gy86_sensor_settings(const gy86_config_t *config, imu_sensor_settings_t *settings)
{
    settings->gyro_scale = mpu6050_gyro_scale(config->mpu.gyro_range);
    settings->acc_scale = mpu6050_acc_scale(config->mpu.acc_range);
    settings->mag_scale = hmc5883l_mag_scale(config->mag.gain);
    settings->gyro_limits[0] = settings->acc_limits[0] = MPU6050_COUNT_MIN;
    settings->gyro_limits[1] = settings->acc_limits[1] = MPU6050_COUNT_MAX;
    settings->mag_limits[0] = HMC5883L_COUNT_MIN;
    settings->mag_limits[1] = HMC5883L_COUNT_MAX;
}
