/**
 * @file imu_navcov.h
 * @brief The block-floating covariance of imu_cov.h for the navigation filter's 16 states:
 *        the same code (imu_navcov.c compiles imu_cov.c again with these names and sizes).
 *
 * A second instance rather than a larger IMU_COV_MAX: imu_cov keeps its work arrays on
 * the stack, sized by its largest state count, and the attitude ESKF's stack budget
 * (1 KiB, issue 12) holds it at nine. Every function is imu_cov's, documented in
 * imu_cov.h; only the sizes differ.
 */
#ifndef IMU_NAVCOV_H
#define IMU_NAVCOV_H

#include "imu_cov.h"

/** Largest number of states. */
#define IMU_NAVCOV_MAX 16
/** Number of stored elements (upper triangle). */
#define IMU_NAVCOV_CELLS (IMU_NAVCOV_MAX * (IMU_NAVCOV_MAX + 1) / 2)

typedef struct {
    int n;                          /**< number of states */
    imu_real_t p[IMU_NAVCOV_CELLS]; /**< upper triangle, row by row; fixed: Q30 mantissas */
    int32_t e[IMU_NAVCOV_MAX];      /**< per-state exponents; 0 in the float build */
} imu_navcov_t;

/** imu_cov_map_t for blocks of three states (the last block holds one). */
typedef struct {
    uint8_t block[(IMU_NAVCOV_MAX + 2) / 3];
    imu_q30_t along[3];
} imu_navcov_map_t;

void imu_navcov_init(imu_navcov_t *c, int n, const imu_wide_t var[], int var_q, uint32_t *sat);
void imu_navcov_predict(imu_navcov_t *c, imu_q30_t rows[][IMU_NAVCOV_MAX], const int moving[], int count,
                        const imu_wide_t qvar[], const imu_wide_t block[6], int qvar_q, uint32_t *sat);
int imu_navcov_update(imu_navcov_t *c, const imu_q30_t h[], imu_wide_t r, int r_q, imu_q30_t z, imu_q30_t w,
                      const imu_navcov_map_t *gain_map, imu_q30_t dx[], uint32_t *sat);
void imu_navcov_reset_state(imu_navcov_t *c, int i, imu_wide_t var, int var_q, uint32_t *sat);
void imu_navcov_cap_unit_variance(imu_navcov_t *c, int i);
void imu_navcov_scale_up(imu_navcov_t *c, const int k[]);
void imu_navcov_get(const imu_navcov_t *c, int i, int j, imu_real_t *mant, int32_t *exp);
imu_real_t imu_navcov_element_q30(const imu_navcov_t *c, int i, int j, uint32_t *sat);
imu_wide_t imu_navcov_element_wide(const imu_navcov_t *c, int i, int j, int q, uint32_t *sat);

#endif /* IMU_NAVCOV_H */
