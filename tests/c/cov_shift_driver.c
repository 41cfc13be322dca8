/* Checks, for tests/test_cov.py, that imu_cov.c's 32-bit shortcuts give the same integers
 * (and count the same saturations) as the 64-bit forms they stand for:
 *   real_ldexp(v, n)     == wide_ldexp(v, n)           an int32 times 2^n, n in [-70, 70]
 *   shifted_int32(v, k)  == min(wide_ldexp(v, -k), INT32_MAX)   |v| < 2^(31 + k), k in [0, 40]
 * over pseudo-random values, the extremes of each range and the values whose rounding
 * is a tie. Prints the number of cases and of differences; exits 1 on any difference.
 * Built with -DIMU_FIXED (the float build has no shifts). */
#include <stdio.h>

#include "imu_cov.c"

static uint64_t state = 88172645463325252u;

static uint64_t next_random(void)
{
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return state;
}

static long cases, differences;

static void check_real(int32_t v, int n)
{
    uint32_t sat_new = 0, sat_old = 0;
    const imu_wide_t got = real_ldexp(v, n, &sat_new);
    const imu_wide_t want = wide_ldexp(v, n, &sat_old);
    ++cases;
    if (got != want || sat_new != sat_old) {
        if (differences++ < 5) {
            printf("real_ldexp(%ld, %d) = %lld, wide_ldexp %lld\n", (long)v, n, (long long)got, (long long)want);
        }
    }
}

static void check_shifted(imu_wide_t v, int k)
{
    uint32_t sat_new = 0, sat_old = 0;
    const imu_real_t got = shifted_int32(v, k, &sat_new);
    const imu_wide_t r = k == 0 ? v : wide_ldexp(v, -k, &sat_old);
    const imu_real_t want = (imu_real_t)(r > INT32_MAX ? INT32_MAX : r);
    ++cases;
    if (got != want || sat_new != sat_old) {
        if (differences++ < 5) {
            printf("shifted_int32(%lld, %d) = %ld, the 64-bit form %ld\n", (long long)v, k, (long)got, (long)want);
        }
    }
}

int main(void)
{
    static const int32_t extremes[] = {0, 1, -1, 2, -2, 3, -3, INT32_MAX, INT32_MIN, INT32_MAX - 1, INT32_MIN + 1,
                                       (int32_t)1 << 30, -((int32_t)1 << 30)};
    long i;
    int n, k, e;
    for (n = -70; n <= 70; ++n) {
        for (e = 0; e < (int)(sizeof extremes / sizeof extremes[0]); ++e) {
            check_real(extremes[e], n);
        }
        for (i = 0; i < 20000; ++i) {
            const uint64_t r = next_random();
            /* full-range values, and small ones whose low bits decide the rounding */
            check_real((int32_t)(uint32_t)r, n);
            check_real((int32_t)(r >> 40) - ((int32_t)1 << 23), n);
        }
    }
    for (k = 0; k <= 40; ++k) {
        const int bits = 31 + k < 62 ? 31 + k : 62; /* |v| < 2^bits */
        const int64_t limit = (int64_t)1 << bits;
        for (i = 0; i < 20000; ++i) {
            const uint64_t r = next_random();
            const int64_t v = (int64_t)(r % ((uint64_t)limit * 2 - 1)) - (limit - 1);
            check_shifted(v, k);
            if (k > 0) {
                /* a tie, m 2^k + 2^(k-1) with |m| < 2^bits / 2^k: the rounding bit set, all below it zero */
                const int64_t m = (int64_t)((r >> 32) % (uint64_t)(limit >> k));
                check_shifted(((r & 1) != 0 ? -m : m) * ((int64_t)1 << k) + ((int64_t)1 << (k - 1)), k);
            }
        }
        check_shifted(limit - 1, k);
        check_shifted(-(limit - 1), k);
        check_shifted(0, k);
    }
    printf("%ld cases, %ld differences\n", cases, differences);
    return differences == 0 ? 0 : 1;
}
