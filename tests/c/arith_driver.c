/* Drives the integer divisions and saturating sums of imu_arith.h for tests/test_arith.py:
 * reads lines
 *   d a b s        -> IMU_DIV_SAT(a, b, s)
 *   u hi lo v      -> imu_udiv64_32(hi 2^32 + lo, v)
 *   + a b          -> IMU_ADD_SAT(a, b)
 *   - a b          -> IMU_SUB_SAT(a, b)
 * from stdin and prints each result and the saturation count. Fixed build only. */
#include <stdio.h>

#include "imu_arith.h"

int main(void)
{
    char op;
    long long a, b, c, s;
    while (scanf(" %c", &op) == 1) {
        uint32_t sat = 0;
        if (op == 'd' && scanf("%lld %lld %lld", &a, &b, &s) == 3) {
            const int32_t q = IMU_DIV_SAT((int32_t)a, (int32_t)b, (int)s, &sat);
            printf("%ld %lu\n", (long)q, (unsigned long)sat);
        } else if (op == 'u' && scanf("%lld %lld %lld", &a, &b, &c) == 3) {
            const uint64_t u = ((uint64_t)a << 32) | (uint64_t)b;
            printf("%lu 0\n", (unsigned long)imu_udiv64_32(u, (uint32_t)c));
        } else if ((op == '+' || op == '-') && scanf("%lld %lld", &a, &b) == 2) {
            const int32_t r = op == '+' ? IMU_ADD_SAT((int32_t)a, (int32_t)b, &sat)
                                        : IMU_SUB_SAT((int32_t)a, (int32_t)b, &sat);
            printf("%ld %lu\n", (long)r, (unsigned long)sat);
        } else {
            fprintf(stderr, "bad input\n");
            return 2;
        }
    }
    return 0;
}
