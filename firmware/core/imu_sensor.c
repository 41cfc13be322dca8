/**
 * @file imu_sensor.c
 * @brief Conversion of raw counts (see imu_sensor.h).
 */
#include "imu_sensor.h"

const imu_sensor_settings_t imu_sensor_default_settings = {
    IMU_QCONST(3.14159265358979323846 / 180.0 / 16.4, 40), /* rad/s per LSB at 16.4 LSB/(deg/s) */
    IMU_QCONST(2.394201660156250e-3, 32),  /* 9.80665 / 4096 */
    IMU_QCONST(9.174311926605504e-2, 24),  /* 100 / 1090 */
};

void imu_sample_from_raw(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw,
                         imu_sample_t *out, uint32_t *sat)
{
    int i;
    out->clipped = 0;
    for (i = 0; i < 3; ++i) {
        if (raw->gyr[i] <= IMU_MPU6050_MIN || raw->gyr[i] >= IMU_MPU6050_MAX) {
            out->clipped |= IMU_CLIPPED_GYR;
        }
        if (raw->acc[i] <= IMU_MPU6050_MIN || raw->acc[i] >= IMU_MPU6050_MAX) {
            out->clipped |= IMU_CLIPPED_ACC;
        }
        if (raw->mag[i] <= IMU_HMC5883L_MIN || raw->mag[i] >= IMU_HMC5883L_MAX) {
            out->clipped |= IMU_CLIPPED_MAG;
        }
        out->gyr[i] = IMU_MUL_SAT(IMU_FROM_INT_SAT(raw->gyr[i], 0, sat), settings->gyro_scale, 16, sat);
        out->acc[i] = IMU_MUL_SAT(IMU_FROM_INT_SAT(raw->acc[i], 0, sat), settings->acc_scale, 16, sat);
        out->mag[i] = IMU_MUL_SAT(IMU_FROM_INT_SAT(raw->mag[i], 0, sat), settings->mag_scale, 8, sat);
    }
}
