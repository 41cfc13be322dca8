/**
 * @file imu_cov.h
 * @brief Symmetric covariance matrix in block-floating form, for Kalman filters
 *        whose variances span many decades (attitude vs bias).
 *
 * Fixed build: P_ij = p_ij * 2^(e_i + e_j - 30), with p stored as int32 (upper
 * triangle only, so P is symmetric by construction) and one exponent e_i per
 * state. After every operation the exponents are renormalised so that each
 * diagonal mantissa p_ii lies in [2^28, 2^30): every variance keeps 28+ bits,
 * whatever its magnitude, and a positive semi-definite P has every |p_ij| below
 * 2^30. In these scaled coordinates the Kalman equations are the ordinary ones
 * (a measurement row h becomes h_j 2^e_j), so each operation below is the textbook
 * formula plus exponent bookkeeping. Float build: p_ij = P_ij, e_i = 0.
 *
 * Scaling and overflow: products are formed in int64; shifts by exponent
 * differences saturate at +-2^62 and count in the caller's counter. A diagonal that
 * rounding drives to zero or below is reset to its smallest normalised value and
 * counted (loss of positive definiteness is never silent). A measurement whose noise
 * dwarfs its row beyond the wide range (a row of rounding-level entries) carries no
 * information: it is skipped, and that is not counted as a saturation.
 */
#ifndef IMU_COV_H
#define IMU_COV_H

#include <stddef.h> /* NULL (imu_cov_predict) */

#include "imu_arith.h"

/** Largest number of states. */
#define IMU_COV_MAX 9
/** Number of stored elements (upper triangle). */
#define IMU_COV_CELLS (IMU_COV_MAX * (IMU_COV_MAX + 1) / 2)

typedef struct {
    int n;                          /**< number of states */
    imu_real_t p[IMU_COV_CELLS];    /**< upper triangle, row by row; fixed: Q30 mantissas */
    int32_t e[IMU_COV_MAX];         /**< per-state exponents; 0 in the float build */
} imu_cov_t;

/**
 * @brief Diagonal covariance.
 * @param var  n variances as wide values in Q`var_q` (fixed build), in the states' units.
 */
void imu_cov_init(imu_cov_t *c, int n, const imu_wide_t var[], int var_q, uint32_t *sat);

/** Most rows of a transition that differ from the identity's (imu_cov_predict): a filter's
 *  transition is mostly identity, and each moving row costs stack. */
#define IMU_COV_MOVING_MAX 3

/** Elements of a symmetric 3 x 3 block (imu_cov_predict): (0,0) (0,1) (0,2) (1,1) (1,2) (2,2). */
#define IMU_COV_BLOCK_CELLS 6

/**
 * @brief Time update P <- Phi P Phi^T + diag(qvar) + B, for a Phi that is the identity but
 *        for `count` rows (at most IMU_COV_MOVING_MAX) and a process noise B of states 0-2
 *        that need not be diagonal.
 * @param rows   those rows of Phi in real units, Q30 (|phi_ij| < 2), row stride IMU_COV_MAX:
 *               rows[t] is row moving[t]; used as scratch: their contents are undefined afterwards.
 * @param moving the states whose rows are given, each once
 * @param qvar   n process-noise variances, wide values in Q`qvar_q` (fixed build).
 * @param block  B's upper triangle (IMU_COV_BLOCK_CELLS, row by row) in the same format, B
 *               positive semi-definite; NULL: none.
 */
void imu_cov_predict(imu_cov_t *c, imu_q30_t rows[][IMU_COV_MAX], const int moving[], int count,
                     const imu_wide_t qvar[], const imu_wide_t block[IMU_COV_BLOCK_CELLS], int qvar_q,
                     uint32_t *sat);

/** What a gain map lets a measurement correct in a block of three states. */
typedef enum {
    IMU_COV_BLOCK_NONE = 0,  /**< nothing (G = 0) */
    IMU_COV_BLOCK_ALL = 1,   /**< everything (G = I) */
    IMU_COV_BLOCK_ALONG = 2, /**< the part along the map's unit vector (G = v v^T) */
} imu_cov_block_t;

/**
 * @brief A block-diagonal gain map G (imu_cov_update): states 0-2, 3-5 and 6-8 each
 *        corrected in full, not at all, or along one unit vector.
 */
typedef struct {
    uint8_t block[IMU_COV_MAX / 3]; /**< imu_cov_block_t of each block of three states */
    imu_q30_t along[3];             /**< the unit vector of the IMU_COV_BLOCK_ALONG blocks, Q30 */
} imu_cov_map_t;

/**
 * @brief Scalar measurement update, z = h x + v, var(v) = r / w.
 *
 * K = w P h / (w h P h + r); P <- P - K h P (symmetric form). The weight w in
 * [0, 1] down-weights a doubtful measurement continuously (w = 0: no update),
 * without forming r / w.
 *
 * A gain map G restricts what the measurement may correct (a Schmidt, or "consider",
 * update): the correction is G K z, and P gets Joseph's form for the gain G K, so it
 * keeps the uncertainty of what was not corrected. NULL: the optimal update (G = I).
 *
 * @param h        n measurement coefficients, Q30, |h_j| < 2, in the states' units
 * @param r        measurement variance, wide value in Q`r_q` (fixed build), > 0
 * @param z        innovation (measured minus predicted), Q30
 * @param w        weight, Q30, [0, 1]
 * @param gain_map NULL, or the map (in the states' units)
 * @param dx       n state corrections, Q30 in the states' units: G K z is added (saturated)
 * @return 1 when updated, 0 when skipped (w = 0)
 */
int imu_cov_update(imu_cov_t *c, const imu_q30_t h[], imu_wide_t r, int r_q, imu_q30_t z, imu_q30_t w,
                   const imu_cov_map_t *gain_map, imu_q30_t dx[], uint32_t *sat);

/** @brief Zero row and column i and set P_ii = var (a wide value in Q`var_q`): the state is reset. */
void imu_cov_reset_state(imu_cov_t *c, int i, imu_wide_t var, int var_q, uint32_t *sat);

/**
 * @brief Keep state i's variance below 1 (its units squared): when it is not, row and
 *        column i are scaled by the power of two that brings P_ii into [1/4, 1).
 *        (An angle error beyond a radian has no meaning in a linearised filter, and an
 *        unbounded variance would make the next correction unbounded too.)
 */
void imu_cov_cap_unit_variance(imu_cov_t *c, int i);

/**
 * @brief P <- D P D, D = diag(2^k[i]), each k[i] in [0, 16]: state i's standard deviation
 *        doubled k[i] times, the correlations kept (a fading memory: the filter trusts its
 *        past less, in the states named).
 */
void imu_cov_scale_up(imu_cov_t *c, const int k[]);

/**
 * @brief Element (i, j) as mantissa and exponent: P_ij = mant * 2^(exp - 30) in the
 *        fixed build; in the float build mant = P_ij and exp = 0.
 */
void imu_cov_get(const imu_cov_t *c, int i, int j, imu_real_t *mant, int32_t *exp);

/** @brief Element (i, j) in Q30 of the states' units (saturated to int32 in the fixed build). */
imu_real_t imu_cov_element_q30(const imu_cov_t *c, int i, int j, uint32_t *sat);

/** @brief Element (i, j) as a wide value in Q`q` of the states' units, q in [0, 62] (saturated
 *         to int64 in the fixed build): for variances too small for Q30. */
imu_wide_t imu_cov_element_wide(const imu_cov_t *c, int i, int j, int q, uint32_t *sat);

#endif /* IMU_COV_H */
