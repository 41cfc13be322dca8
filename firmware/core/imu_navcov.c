/**
 * @file imu_navcov.c
 * @brief imu_cov.c compiled for the navigation filter's 16 states (see imu_navcov.h): its
 *        names and sizes replaced, its code the same.
 */
#include "imu_navcov.h"

#undef IMU_COV_MAX
#define IMU_COV_MAX IMU_NAVCOV_MAX
#undef IMU_COV_CELLS
#define IMU_COV_CELLS IMU_NAVCOV_CELLS
#define imu_cov_t imu_navcov_t
#define imu_cov_map_t imu_navcov_map_t
#define imu_cov_init imu_navcov_init
#define imu_cov_predict imu_navcov_predict
#define imu_cov_update imu_navcov_update
#define imu_cov_reset_state imu_navcov_reset_state
#define imu_cov_cap_unit_variance imu_navcov_cap_unit_variance
#define imu_cov_scale_up imu_navcov_scale_up
#define imu_cov_get imu_navcov_get
#define imu_cov_element_q30 imu_navcov_element_q30
#define imu_cov_element_wide imu_navcov_element_wide

#include "imu_cov.c"
