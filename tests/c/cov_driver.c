/* Drives imu_cov.c for tests/test_cov.py: reads from stdin
 *   n, then n initial variances, then steps until EOF, each either
 *   u h[n] r z w has_map [block[(n + 2) / 3] v[3]]
 * a measurement update (a gain map: each block of three states 0 none, 1 all, 2 along the
 * unit vector v), or
 *   p count moving[count] rows[count][n] qvar[n] block[6]
 * a time update whose transition is the identity but for the given rows (process noise
 * diag(qvar) plus a block of states 0-2, its upper triangle row by row; all zero: none),
 * (real values) and prints after each step "dx" (zero for a time update) and the n x n
 * covariance as reals. Built twice, with -DIMU_FIXED and -DIMU_FLOAT; with -DNAVCOV, for
 * the navigation filter's 15-state instance (imu_navcov.c) instead of imu_cov.c. */
#include <math.h>
#include <stdio.h>

#ifdef NAVCOV
#include "imu_navcov.h"
#undef IMU_COV_MAX
#define IMU_COV_MAX IMU_NAVCOV_MAX
#define imu_cov_t imu_navcov_t
#define imu_cov_map_t imu_navcov_map_t
#define imu_cov_init imu_navcov_init
#define imu_cov_predict imu_navcov_predict
#define imu_cov_update imu_navcov_update
#define imu_cov_get imu_navcov_get
#else
#include "imu_cov.h"
#endif

#ifdef IMU_FIXED
/* Q formats of the inputs: variances, process noise and r in Q60 (below 8); h, z, w, v and
 * the rows of phi in Q30. */
#define TO_WIDE(x) ((imu_wide_t)llround((x) * 1152921504606846976.0))
#define TO_Q30(x) ((imu_q30_t)lround((x) * 1073741824.0))
#define FROM_Q30(x) ((double)(x) / 1073741824.0)
#define MANT_Q 30 /* P_ij = mant 2^(exp - 30) */
#else
#define TO_WIDE(x) (x)
#define TO_Q30(x) (x)
#define FROM_Q30(x) (x)
#define MANT_Q 0
#endif

static void print_step(const imu_cov_t *cov, int n, const imu_q30_t dx[])
{
    int i, j;
    printf("dx");
    for (i = 0; i < n; ++i) {
        printf(" %.17g", FROM_Q30(dx[i]));
    }
    printf("\nP");
    for (i = 0; i < n; ++i) {
        for (j = 0; j < n; ++j) {
            imu_real_t mant;
            int32_t e;
            imu_cov_get(cov, i, j, &mant, &e);
            printf(" %.17g", (double)mant * ldexp(1.0, (int)e - MANT_Q));
        }
    }
    printf("\n");
}

int main(void)
{
    imu_cov_t cov;
    imu_wide_t var[IMU_COV_MAX];
    uint32_t sat = 0;
    int n, i, j;
    double v;
    if (scanf("%d", &n) != 1 || n < 1 || n > IMU_COV_MAX) {
        return 2;
    }
    for (i = 0; i < n; ++i) {
        if (scanf("%lf", &v) != 1) {
            return 2;
        }
        var[i] = TO_WIDE(v);
    }
    imu_cov_init(&cov, n, var, 60, &sat);
    for (;;) {
        imu_q30_t h[IMU_COV_MAX], dx[IMU_COV_MAX];
        imu_cov_map_t map;
        double r, z, w;
        int has_map, kind;
        char step[2];
        if (scanf("%1s", step) != 1) {
            printf("saturations %u\n", (unsigned)sat);
            return 0;
        }
        for (i = 0; i < n; ++i) {
            dx[i] = 0;
        }
        if (step[0] == 'p') {
            imu_q30_t rows[IMU_COV_MOVING_MAX][IMU_COV_MAX];
            imu_wide_t block[6]; /* (0,0) (0,1) (0,2) (1,1) (1,2) (2,2) */
            int moving[IMU_COV_MOVING_MAX], count, t, any_block = 0;
            if (scanf("%d", &count) != 1 || count < 0 || count > IMU_COV_MOVING_MAX) {
                return 2;
            }
            for (t = 0; t < count; ++t) {
                if (scanf("%d", &moving[t]) != 1 || moving[t] < 0 || moving[t] >= n) {
                    return 2;
                }
            }
            for (t = 0; t < count; ++t) {
                for (j = 0; j < n; ++j) {
                    if (scanf("%lf", &v) != 1) {
                        return 2;
                    }
                    rows[t][j] = TO_Q30(v);
                }
            }
            for (i = 0; i < n; ++i) {
                if (scanf("%lf", &v) != 1) {
                    return 2;
                }
                var[i] = TO_WIDE(v);
            }
            for (i = 0; i < 6; ++i) {
                if (scanf("%lf", &v) != 1) {
                    return 2;
                }
                block[i] = TO_WIDE(v);
                any_block = any_block || v != 0.0;
            }
            imu_cov_predict(&cov, rows, moving, count, var, any_block ? block : NULL, 60, &sat);
            print_step(&cov, n, dx);
            continue;
        }
        if (step[0] != 'u') {
            return 2;
        }
        for (i = 0; i < n; ++i) {
            if (scanf("%lf", &v) != 1) {
                return 2;
            }
            h[i] = TO_Q30(v);
        }
        if (scanf("%lf %lf %lf %d", &r, &z, &w, &has_map) != 4) {
            return 2;
        }
        for (i = 0; i < (n + 2) / 3 && has_map; ++i) {
            if (scanf("%d", &kind) != 1 || kind < 0 || kind > 2) {
                return 2;
            }
            map.block[i] = (uint8_t)kind;
        }
        for (i = 0; i < 3 && has_map; ++i) {
            if (scanf("%lf", &v) != 1) {
                return 2;
            }
            map.along[i] = TO_Q30(v);
        }
        (void)imu_cov_update(&cov, h, TO_WIDE(r), 60, TO_Q30(z), TO_Q30(w), has_map ? &map : NULL, dx, &sat);
        print_step(&cov, n, dx);
    }
}
