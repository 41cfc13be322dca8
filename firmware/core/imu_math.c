/**
 * @file imu_math.c
 * @brief Vector, quaternion and angle helpers (see imu_math.h).
 *
 * The fixed build uses integer square roots and, for atan2 and sin/cos, tables with
 * short Taylor series (imu_math_tables.h, about 1e-9 rad); the float build calls the
 * C library. Both builds share the formulas above that level.
 */
#include "imu_math.h"

#ifdef IMU_FIXED
#include "imu_math_tables.h"
#endif

#ifdef IMU_FLOAT
#include <math.h>
#endif

#ifdef IMU_FIXED

/**
 * floor(sqrt(v)) without a 64-bit division (the Cortex-M4 divides 32 by 32 bits in one
 * instruction, 64 bits only in a library routine of some hundred instructions).
 *
 * v is scaled by 4^k so that n = v 4^k lies in [2^62, 2^64): floor(sqrt(v)) =
 * floor(sqrt(n)) >> k. Its top 32 bits `top` (in [2^30, 2^32)) have the root r =
 * floor(sqrt(top)) in [2^15, 2^16): two Newton steps r <- (r + top / r) / 2 from a
 * linear first guess (within 6 %: then 2e-3, then 2e-6, i.e. below 1 of r) and a
 * final check make it exact. sqrt(n) lies in [r 2^16, (r + 1) 2^16): one Newton step
 * from R = r 2^16 with the remainder d = n - R^2 in [0, (2r + 1) 2^32) adds
 * c = d / (2R) = (d / 2^17) / r, below 2^16 + 1 and a 32-bit division; the step lands
 * above the root by at most c^2 / (2R) <= 1, below by the division's truncations (at
 * most 1). The last checks bring R to floor(sqrt(n)) exactly: the result equals the
 * digit-by-digit root for every v (tests/test_math.py compares with Python's isqrt).
 */
static uint32_t isqrt64(uint64_t v)
{
    int k;
    uint64_t n;
    uint32_t top, r, c, root;
    uint64_t wide_root, d;
    if (v == 0) {
        return 0;
    }
    k = (64 - imu_bit_length64(v)) >> 1;
    n = v << (2 * k);
    top = (uint32_t)(n >> 32);
    /* sqrt(x) on [2^30, 2^32] within 4.2 %: (0.35417 + 2/3 x / 2^32) 2^16. */
    r = 23211 + ((top / 3) >> 15);
    r = (r + top / r) >> 1;
    r = (r + top / r) >> 1;
    while ((uint64_t)r * r > top) {
        --r;
    }
    while ((uint64_t)(r + 1) * (r + 1) <= top) {
        ++r;
    }
    wide_root = (uint64_t)r << 16;
    d = n - wide_root * wide_root;       /* in [0, (2r + 1) 2^32) */
    c = (uint32_t)(d >> 17) / r;         /* d / 2^17 < (2r + 1) 2^15 < 2^32 */
    wide_root += c;
    /* floor(sqrt(n)) < 2^32: from here on a uint32, each square one 32 x 32 -> 64-bit multiply */
    root = wide_root > UINT32_MAX ? UINT32_MAX : (uint32_t)wide_root;
    while ((uint64_t)root * root > n) {
        --root;
    }
    while (root < UINT32_MAX && (uint64_t)(root + 1) * (root + 1) <= n) {
        ++root;
    }
    return root >> k;
}

/** |v| as uint32 (2^31 for INT32_MIN). */
static uint32_t abs32(int32_t v)
{
    return v < 0 ? (uint32_t)(-(int64_t)v) : (uint32_t)v;
}

int imu_vec3_normalize(const imu_real_t v[3], imu_q30_t unit[3], imu_real_t *norm)
{
    /* Magnitudes scaled so that the largest is in [2^29, 2^31]: the sum of squares is
     * below 3 * 2^62 < 2^64 and the root below 2^32. In uint32, each square and each
     * product below is one 32 x 32 -> 64-bit multiply. */
    uint32_t m[3];
    uint32_t largest;
    uint64_t sum = 0;
    uint64_t inv;
    uint32_t n;
    int shift;
    int i;
    for (i = 0; i < 3; ++i) {
        m[i] = abs32(v[i]);
    }
    largest = m[0] > m[1] ? m[0] : m[1];
    largest = largest > m[2] ? largest : m[2];
    if (largest == 0) {
        return 0;
    }
    shift = imu_clz32(largest) - 2; /* 30 - bit length */
    if (shift < 0) {
        shift = 0;
    }
    for (i = 0; i < 3; ++i) {
        m[i] <<= shift;
        sum += (uint64_t)m[i] * m[i];
    }
    n = isqrt64(sum); /* at least 2^29 */
    /* 1/n in Q61 (n >= 2^29: at most 2^32, exactly 2^32 for n = 2^29); m <= n keeps
     * m * inv at most 2^63 and the Q30 result within 2^30. */
    inv = unit != 0 ? (uint64_t)imu_udiv_or_big((uint64_t)1 << 61, n) : 0;
    for (i = 0; unit != 0 && i < 3; ++i) {
        /* The signed product (+-m inv) rounded by (x + 2^30) >> 31, ties toward +inf:
         * for -m that is -((m inv + 2^30 - 1) >> 31). */
        const uint64_t p = (uint64_t)m[i] * inv;
        unit[i] = v[i] < 0 ? -(imu_q30_t)((p + ((uint64_t)1 << 30) - 1) >> 31)
                           : (imu_q30_t)((p + ((uint64_t)1 << 30)) >> 31);
    }
    if (norm != 0) {
        const uint64_t unscaled = ((uint64_t)n + (((uint64_t)1 << shift) >> 1)) >> shift;
        *norm = unscaled > INT32_MAX ? INT32_MAX : (imu_real_t)unscaled;
    }
    return 1;
}

imu_real_t imu_vec3_norm(const imu_real_t v[3])
{
    /* three squares, each at most 2^62: the sum is below 2^64 */
    const uint64_t sum = (uint64_t)((int64_t)v[0] * v[0]) + (uint64_t)((int64_t)v[1] * v[1]) +
                         (uint64_t)((int64_t)v[2] * v[2]);
    const uint64_t root = isqrt64(sum);
    /* sqrt(sum) >= root + 1/2 exactly when sum - root^2 > root (integers): rounded up */
    const uint64_t rounded = root + (sum - root * root > root ? 1 : 0);
    return rounded > INT32_MAX ? INT32_MAX : (imu_real_t)rounded;
}

imu_real_t imu_hypot(imu_real_t a, imu_real_t b)
{
    const uint64_t sum = (uint64_t)((int64_t)a * a) + (uint64_t)((int64_t)b * b);
    const uint32_t n = isqrt64(sum);
    return n > INT32_MAX ? INT32_MAX : (imu_real_t)n;
}

void imu_quat_normalize(imu_q30_t q[4])
{
    uint64_t sum = 0;
    int64_t inv;
    int i;
    for (i = 0; i < 4; ++i) {
        sum += (uint64_t)((int64_t)q[i] * q[i]); /* |q| at most 2: sum below 2^64 */
    }
    {
        /* |q|^2 - 1 in Q60. Within 2^-10 of unit norm (every step of a filter),
         * one Newton step for 1/sqrt(x) around 1, (3 - x) / 2, is exact to
         * ~1e-6 * (x - 1) and needs no square root. */
        const int64_t excess = (int64_t)sum - ((int64_t)1 << 60); /* sum below 2^62: exact */
        if (excess < ((int64_t)1 << 50) && excess > -((int64_t)1 << 50)) {
            inv = ((int64_t)1 << 30) - imu_rshift_round64(excess, 31); /* Q30 */
        } else {
            const uint32_t n = isqrt64(sum); /* |q| in Q30 */
            if (n == 0) {
                q[0] = IMU_ONE_Q30;
                q[1] = q[2] = q[3] = 0;
                return;
            }
            inv = ((int64_t)1 << 60) / (int64_t)n; /* 1/|q| in Q30 */
        }
    }
    for (i = 0; i < 4; ++i) {
        q[i] = (imu_q30_t)imu_rshift_round64((int64_t)q[i] * inv, 30);
    }
}

/** pi and pi/2 in rad, Q32 (do not fit int32). */
#define PI_Q32 INT64_C(13493037705)
#define HALF_PI_Q32 INT64_C(6746518852)

/** 2*pi in Q29 (does not fit int32). */
#define TWO_PI_ANGLE64 INT64_C(3373259426)

/**
 * atan2 by octant: t = min(|x|, |y|) / max(|x|, |y|) in [0, 1] as floor(t 2^32)
 * (2^32 - 1 for t = 1; one 64-by-32-bit division, imu_udiv64_32), atan(t) by the Taylor polynomial of degree 4 around
 * the nearest table point i/64 (imu_math_tables.h: truncation below 3e-11 rad,
 * coefficients rounded to 2^-32) in Q32, then the octant's pi/2 - a, pi - a and sign,
 * and one rounding of the magnitude to Q29 (so atan2(-y, x) = -atan2(y, x) below pi,
 * and +-pi/2 are exact). Error below 2e-9 rad (the Q29 rounding alone 9.3e-10; 1.6e-9
 * the largest of 2e7 random pairs); about 90 Cortex-M4 instructions where the 31-step
 * CORDIC in int64 took 1 300.
 */
imu_angle_t imu_atan2(imu_real_t y, imu_real_t x)
{
    const uint32_t ax = x < 0 ? (uint32_t)(-(int64_t)x) : (uint32_t)x;
    const uint32_t ay = y < 0 ? (uint32_t)(-(int64_t)y) : (uint32_t)y;
    const int steep = ay > ax;
    uint32_t num = steep ? ax : ay;
    uint32_t den = steep ? ay : ax;
    int64_t a; /* rad, Q32, in [0, pi] */
    imu_angle_t r;
    if (den == 0) {
        return 0;
    }
    {
        const int shift = 32 - imu_bit_length64(den);
        num <<= shift;
        den <<= shift;
    }
    {
        const uint32_t t = num == den ? UINT32_MAX : imu_udiv64_32((uint64_t)num << 32, den);
        const uint32_t i = ((t >> 25) + 1u) >> 1;                            /* nearest i/64, 0..64 */
        const int32_t h = (int32_t)((int64_t)t - ((int64_t)i << 26));       /* Q32, |h| <= 2^25 */
        const imu_atan_segment_t *c = &imu_atan_taylor[i];
        /* Horner in Q31 with 32-bit terms (|p h| < 2^56); the degree-1 coefficient is
         * taken as 1 + (a1 - 1), so that its term fits too: a1 h = h + (a1 - 1) h. */
        int32_t p = c->a4;
        p = c->a3 + (int32_t)(((int64_t)p * h) >> 32);
        p = c->a2 + (int32_t)(((int64_t)p * h) >> 32);
        p = (int32_t)((int64_t)c->a1 - ((int64_t)1 << 31)) + (int32_t)(((int64_t)p * h) >> 32); /* in [-2^30, 0] */
        a = (int64_t)c->a0 + h + (((int64_t)p * h) >> 31);
    }
    if (steep) {
        a = HALF_PI_Q32 - a;
    }
    if (x < 0) {
        a = PI_Q32 - a;
    }
    r = (imu_angle_t)imu_rshift_round64(a, 3); /* at most pi */
    return y < 0 && r != IMU_PI_ANGLE ? -r : r; /* -pi (a tiny y < 0 beside -x) is pi */
}

/** Wrap an int64 Q29 angle within +-3 turns to (-pi, pi]. */
static imu_angle_t wrap64(int64_t v)
{
    while (v > IMU_PI_ANGLE) {
        v -= TWO_PI_ANGLE64;
    }
    while (v <= -(int64_t)IMU_PI_ANGLE) {
        v += TWO_PI_ANGLE64;
    }
    return (imu_angle_t)v;
}

imu_angle_t imu_wrap_angle(imu_angle_t a)
{
    return wrap64(a);
}

imu_angle_t imu_angle_add(imu_angle_t a, imu_angle_t b)
{
    return wrap64((int64_t)a + b);
}

imu_angle_t imu_angle_diff(imu_angle_t a, imu_angle_t b)
{
    return wrap64((int64_t)a - b);
}

/**
 * sin and cos from the table at x_i = i/64 <= b (imu_math_tables.h, Q31) and the
 * Taylor series of the rest h in [0, 1/64): sin(x_i + h) = S (1 + u) + C sin h,
 * cos(x_i + h) = C (1 + u) - S sin h with u = cos h - 1 = -h^2/2 + h^4/24 and
 * sin h = h - h^3/6 (truncation below 1e-11), both in Q36; summed in Q62 and rounded
 * once to Q30. Error below 8e-10 (table 2.3e-10, rounding 4.7e-10); the angle is first
 * reduced to b = |a| in [0, pi/2] with the signs and pi - b of the quadrant (the Q29 pi
 * is 0.06 LSB from pi). About 80 Cortex-M4 instructions (the CORDIC took 1 150).
 */
void imu_sincos(imu_angle_t angle, imu_q30_t *s, imu_q30_t *c)
{
    const imu_angle_t a = imu_wrap_angle(angle); /* Q29, (-pi, pi] */
    int32_t b = a < 0 ? -a : a;
    int negate_cos = 0;
    int32_t i;
    int32_t h, h2, sin_h, u; /* Q36 */
    int64_t sin_b, cos_b;    /* Q62 */
    if (b > IMU_HALF_PI_ANGLE) {
        b = IMU_PI_ANGLE - b;
        negate_cos = 1;
    }
    i = b >> (IMU_QANGLE - IMU_TABLE_SHIFT);          /* at most 100 */
    h = (b - (i << (IMU_QANGLE - IMU_TABLE_SHIFT))) * 128; /* Q29 -> Q36, below 2^30 */
    h2 = (int32_t)(((int64_t)h * h) >> 36);            /* below 2^24 */
    sin_h = h - (int32_t)(((int64_t)h2 * h) >> 36) / 6;
    u = -(h2 / 2) + (int32_t)(((int64_t)h2 * h2) >> 36) / 24;
    {
        const int64_t sx = imu_sin_q31[i];
        const int64_t cx = imu_cos_q31[i];
        /* Q31 * Q36 = Q67 (below 2^61) >> 5 -> Q62; S 2^31 at most 2^62. */
        sin_b = sx * ((int64_t)1 << 31) + ((sx * u + cx * sin_h) >> 5);
        cos_b = cx * ((int64_t)1 << 31) + ((cx * u - sx * sin_h) >> 5);
    }
    {
        const imu_q30_t sv = (imu_q30_t)imu_rshift_round64(sin_b, 32);
        const imu_q30_t cv = (imu_q30_t)imu_rshift_round64(cos_b, 32);
        *s = a < 0 ? -sv : sv;
        *c = negate_cos ? -cv : cv;
    }
}

/** imu_quat_turn's series bound: |theta|^2 below 2^-12 rad^2 (|theta| < 1/64 rad), in Q60. */
#define TURN_SERIES_LIMIT ((uint64_t)1 << 48)

/** (v >> s) rounded to nearest, ties to even, for s in [1, 62] and |v| < 2^62. Unbiased
 *  and odd-symmetric (v and -v give opposite results): unlike ties toward +inf, the
 *  rounding adds no drift of its own direction. (int64_t is two's complement: the mask
 *  reads the low bits of negative values too.) */
static int64_t rshift_round_even64(int64_t v, int s)
{
    const int64_t half = (int64_t)1 << (s - 1);
    int64_t r = (v + half) >> s; /* ties up */
    if ((v & (((int64_t)1 << s) - 1)) == half && (r & 1) != 0) {
        r -= 1; /* a tie went up to an odd value: its even neighbour is one below */
    }
    return r;
}

/**
 * quat_mul_step: r = q (x) (w, v) in Q61, exact. quat_mul_step_normalized:
 * q <- normalize(q (x) (w, v)): the product with a rotation step whose vector part v
 * carries one more fraction bit than the quaternion (w: Q30, v: Q31, |v| <= sin(1/2)),
 * so that the half angle of a small step is exact instead of rounded to Q30, and the
 * normalisation applied before the one rounding to Q30.
 *
 * Product: the w terms are doubled to Q61 and every sum is formed exactly in int64:
 * each output is sum_i +-q_a(i) d_i over the four components d of the step, so every
 * partial sum is at most |q| |(w, v)| (Cauchy-Schwarz): below 2^62 (Q61) while
 * |q| |(w, v)| < 2 (unit quaternions, up to |q| = 2 as imu_quat_normalize takes).
 *
 * Normalisation: |q (x) dq|^2 = |q|^2 |dq|^2 = 1 + eps with eps from the two norms
 * (Q58, exact to 2^-58). For |eps| < 2^-11 (every filter step: q was normalised by the
 * previous step, the step's series are exact to 2e-5) the product is scaled by
 * 1/sqrt(1 + eps) = 1 - eps/2 + 3 eps^2/8 (error below 2^-34) in Q61, and rounded
 * once, ties to even. Rounding first and scaling by a factor quantised to Q30 (as
 * imu_quat_normalize does) shortens the components above 1/2 by one LSB while those
 * below keep theirs: a rotation about the attitude's own axis of up to 1e-9 rad per
 * step, the same whichever way the board turns. Larger eps: rounded, then
 * imu_quat_normalize.
 */
static void quat_mul_step(const imu_q30_t q[4], imu_q30_t w, const int32_t v[3], int64_t r[4])
{
    const int64_t w2 = (int64_t)w * 2; /* Q31 */
    r[0] = (int64_t)q[0] * w2 - (int64_t)q[1] * v[0] - (int64_t)q[2] * v[1] - (int64_t)q[3] * v[2];
    r[1] = (int64_t)q[0] * v[0] + (int64_t)q[1] * w2 + (int64_t)q[2] * v[2] - (int64_t)q[3] * v[1];
    r[2] = (int64_t)q[0] * v[1] - (int64_t)q[1] * v[2] + (int64_t)q[2] * w2 + (int64_t)q[3] * v[0];
    r[3] = (int64_t)q[0] * v[2] + (int64_t)q[1] * v[1] - (int64_t)q[2] * v[0] + (int64_t)q[3] * w2;
}

/** q <- the product r (Q61) of quat_mul_step with the step (w, v), normalised and rounded;
 *  a = |q|^2 - 1 of the quaternion it was formed from (Q58). */
static inline void store_normalized_product(imu_q30_t q[4], const int64_t r[4], int64_t a, imu_q30_t w,
                                            const int32_t v[3])
{
    const int64_t one58 = (int64_t)1 << 58;
    const int64_t near = (int64_t)1 << 47; /* 2^-11 in Q58 */
    int64_t b;                             /* |dq|^2 - 1, Q58 */
    int i;
    /* w^2 (Q60, w <= 2^30) / 4 plus |v|^2 (Q62, each v at most 2^30) / 16: below 2^59. */
    b = (((int64_t)w * w) >> 2) + (((int64_t)v[0] * v[0]) >> 4) + (((int64_t)v[1] * v[1]) >> 4) +
        (((int64_t)v[2] * v[2]) >> 4) - one58;
    if (a < near && a > -near && b < near && b > -near) {
        /* eps = a + b + a b, Q58, |eps| < 2^49 (|a b| < 2^36 from the Q29 factors). */
        const int64_t eps = a + b + (int64_t)(int32_t)(a >> 29) * (int32_t)(b >> 29);
        const int32_t eps29 = (int32_t)(eps >> 29); /* Q29, |eps29| < 2^20 */
        /* k = eps/2 - 3 eps^2/8 in Q40 (|k| < 2^30): Q58 >> 19, and Q58 >> 21 for 3/8. The
         * factors of each product here fit int32: one 32 x 32 -> 64-bit multiply each. */
        const int32_t k = (int32_t)((eps >> 19) - (((int64_t)(3 * eps29) * eps29) >> 21));
        for (i = 0; i < 4; ++i) {
            /* r (Q61, |r| < 2^62) >> 31 is Q30 below 2^31; times k (Q40) is Q70 below 2^61;
             * >> 9 -> Q61. The truncations cost 2^-9 LSB of the result. */
            const int64_t c = ((int64_t)(int32_t)(r[i] >> 31) * k) >> 9;
            q[i] = IMU_NARROW(rshift_round_even64(r[i] - c, 31)); /* |r - c| < 2^62: below 2^31 */
        }
        return;
    }
    for (i = 0; i < 4; ++i) {
        q[i] = IMU_NARROW(rshift_round_even64(r[i], 31)); /* |r| < 2^62: below 2^31 */
    }
    imu_quat_normalize(q);
}

static void quat_mul_step_normalized(imu_q30_t q[4], imu_q30_t w, const int32_t v[3])
{
    int64_t r[4];                      /* the product, Q61 */
    int64_t a = -((int64_t)1 << 58);   /* |q|^2 - 1, Q58: four squares (< 2^62) / 4, minus 1 */
    int i;
    quat_mul_step(q, w, v, r);
    for (i = 0; i < 4; ++i) {
        a += ((int64_t)q[i] * q[i]) >> 2; /* at most 2^60 each: the sum stays below 2^62 */
    }
    store_normalized_product(q, r, a, w, v);
}

/** quat_mul_step_normalized of the identity (2^30, 0, 0, 0), the same integers: its product
 *  with the step is the step itself in Q61 and its norm is exact (a = 0), so neither the
 *  sixteen products nor the four squares are formed. */
static void identity_step_normalized(imu_q30_t q[4], imu_q30_t w, const int32_t v[3])
{
    const int64_t r[4] = {(int64_t)w * ((int64_t)1 << 31), (int64_t)v[0] * ((int64_t)1 << 30),
                          (int64_t)v[1] * ((int64_t)1 << 30), (int64_t)v[2] * ((int64_t)1 << 30)};
    store_normalized_product(q, r, 0, w, v);
}

/** The rotation step of theta (Q30 rad): w = cos(x) (Q30) and v = sin(x) theta / |theta| (Q31),
 *  x = |theta| / 2, |theta| limited to 1 rad. */
static inline void rotation_step(const imu_q30_t theta[3], imu_q30_t *w, int32_t half_step[3])
{
    /* |theta|^2 in Q60 (three squares below 2^62 each: below 2^64 unsigned). */
    uint64_t sum = (uint64_t)((int64_t)theta[0] * theta[0]) + (uint64_t)((int64_t)theta[1] * theta[1]) +
                   (uint64_t)((int64_t)theta[2] * theta[2]);
    imu_q30_t step[3];
    int32_t x2;
    int i;
    for (i = 0; i < 3; ++i) {
        step[i] = theta[i];
    }
    if (sum > ((uint64_t)1 << 60)) {
        /* Longer than MAX_STEP (1 rad): keep the direction, limit the length. */
        const int64_t len = isqrt64(sum); /* Q30, 2^30 .. 2^32 */
        for (i = 0; i < 3; ++i) {
            step[i] = (imu_q30_t)(((int64_t)theta[i] * ((int64_t)1 << 30)) / len);
        }
        sum = (uint64_t)1 << 60;
    }
    /* x = |step| / 2; x^2 in Q30 from the Q60 sum shifted by 32 (at most 2^28). */
    x2 = (int32_t)imu_rshift_round64((int64_t)sum, 32);
    const int32_t x4 = imu_mul(x2, x2, 30);
    /* cos x = 1 - x^2/2 + x^4/24; sin(x)/x = 1 - x^2/6 + x^4/120 (Q30). */
    const int32_t sinc_x = IMU_ONE_Q30 - x2 / 6 + x4 / 120;
    *w = IMU_ONE_Q30 - x2 / 2 + x4 / 24;
    for (i = 0; i < 3; ++i) {
        /* sinc (<= 2^30) * step (|step| <= 2^30) / 2 in Q31: Q60 >> 30, magnitude at
         * most 2^30. Exact for steps below 4.3e-5 rad (sinc = 1); otherwise rounded
         * symmetrically, so a step and its opposite give opposite half angles. (In Q30
         * with ties toward +inf every odd step gained 2^-31 of half angle whatever its
         * sign: a drift of 9.3e-10 rad per step on each axis.) */
        half_step[i] = IMU_NARROW(rshift_round_even64((int64_t)sinc_x * step[i], 30));
    }
}

void imu_quat_integrate(imu_q30_t q[4], const imu_q30_t theta[3])
{
    imu_q30_t w;
    int32_t half_step[3]; /* sin(x) * step / |step| = sinc * step / 2, Q31 */
    rotation_step(theta, &w, half_step);
    quat_mul_step_normalized(q, w, half_step);
}

void imu_quat_from_rotation(imu_q30_t q[4], const imu_q30_t theta[3])
{
    imu_q30_t w;
    int32_t half_step[3];
    rotation_step(theta, &w, half_step);
    identity_step_normalized(q, w, half_step);
}

void imu_quat_turn(imu_q30_t q[4], const imu_q30_t theta[3])
{
    /* |theta|^2 in Q60, as in imu_quat_integrate */
    const uint64_t sum = (uint64_t)((int64_t)theta[0] * theta[0]) + (uint64_t)((int64_t)theta[1] * theta[1]) +
                         (uint64_t)((int64_t)theta[2] * theta[2]);
    if (sum < TURN_SERIES_LIMIT) {
        /* w = 1 - |theta|^2 / 8 (Q30: Q60 >> 33); the half angle theta/2 in Q31 is theta's Q30 integer. */
        const imu_q30_t w = IMU_ONE_Q30 - (imu_q30_t)imu_rshift_round64((int64_t)sum, 33);
        int64_t r[4]; /* Q61 */
        int i;
        quat_mul_step(q, w, theta, r);
        for (i = 0; i < 4; ++i) {
            q[i] = IMU_NARROW(rshift_round_even64(r[i], 31));
        }
        return;
    }
    imu_quat_integrate(q, theta);
}

/** Sum of two Q30 products (Q60 in int64). */
#define P2(a, b, c, d) ((int64_t)(a) * (b) + (int64_t)(c) * (d))

void imu_quat_matrix_row(const imu_q30_t q[4], int row, imu_q30_t out[3])
{
    const int64_t one = (int64_t)1 << 60;
    int64_t r[3];
    switch (row) {
    case 0:
        r[0] = one - 2 * P2(q[2], q[2], q[3], q[3]);
        r[1] = 2 * P2(q[1], q[2], -q[0], q[3]);
        r[2] = 2 * P2(q[1], q[3], q[0], q[2]);
        break;
    case 1:
        r[0] = 2 * P2(q[1], q[2], q[0], q[3]);
        r[1] = one - 2 * P2(q[1], q[1], q[3], q[3]);
        r[2] = 2 * P2(q[2], q[3], -q[0], q[1]);
        break;
    default:
        r[0] = 2 * P2(q[1], q[3], -q[0], q[2]);
        r[1] = 2 * P2(q[2], q[3], q[0], q[1]);
        r[2] = one - 2 * P2(q[1], q[1], q[2], q[2]);
        break;
    }
    out[0] = (imu_q30_t)imu_rshift_round64(r[0], 30);
    out[1] = (imu_q30_t)imu_rshift_round64(r[1], 30);
    out[2] = (imu_q30_t)imu_rshift_round64(r[2], 30);
}

void imu_quat_y_axis(const imu_q30_t q[4], imu_q30_t out[3])
{
    out[0] = (imu_q30_t)imu_rshift_round64(2 * P2(q[1], q[2], -q[0], q[3]), 30);
    out[1] = (imu_q30_t)imu_rshift_round64(((int64_t)1 << 60) - 2 * P2(q[1], q[1], q[3], q[3]), 30);
    out[2] = (imu_q30_t)imu_rshift_round64(2 * P2(q[2], q[3], q[0], q[1]), 30);
}

#undef P2

#else /* IMU_FLOAT */

int imu_vec3_normalize(const imu_real_t v[3], imu_q30_t unit[3], imu_real_t *norm)
{
    const double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    int i;
    if (n == 0.0) {
        return 0;
    }
    for (i = 0; unit != 0 && i < 3; ++i) {
        unit[i] = v[i] / n;
    }
    if (norm != 0) {
        *norm = n;
    }
    return 1;
}

imu_real_t imu_vec3_norm(const imu_real_t v[3])
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

imu_real_t imu_hypot(imu_real_t a, imu_real_t b)
{
    return sqrt(a * a + b * b);
}

void imu_quat_normalize(imu_q30_t q[4])
{
    const double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    int i;
    if (n == 0.0) {
        q[0] = 1.0;
        q[1] = q[2] = q[3] = 0.0;
        return;
    }
    for (i = 0; i < 4; ++i) {
        q[i] /= n;
    }
}

imu_angle_t imu_atan2(imu_real_t y, imu_real_t x)
{
    return (x == 0.0 && y == 0.0) ? 0.0 : imu_wrap_angle(atan2(y, x));
}

imu_angle_t imu_wrap_angle(imu_angle_t a)
{
    const double pi = 3.14159265358979323846;
    while (a > pi) {
        a -= 2.0 * pi;
    }
    while (a <= -pi) {
        a += 2.0 * pi;
    }
    return a;
}

imu_angle_t imu_angle_add(imu_angle_t a, imu_angle_t b)
{
    return imu_wrap_angle(a + b);
}

imu_angle_t imu_angle_diff(imu_angle_t a, imu_angle_t b)
{
    return imu_wrap_angle(a - b);
}

void imu_sincos(imu_angle_t angle, imu_q30_t *s, imu_q30_t *c)
{
    *s = sin(angle);
    *c = cos(angle);
}

void imu_quat_integrate(imu_q30_t q[4], const imu_q30_t theta[3])
{
    const double len = sqrt(theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]);
    const double limit = len > 1.0 ? 1.0 / len : 1.0; /* steps above 1 rad are limited to 1 rad */
    const double x = 0.5 * len * limit;
    const double half_sinc = (x > 1e-9 ? 0.5 * sin(x) / x : 0.5 * (1.0 - x * x / 6.0)) * limit;
    const double dq[4] = {cos(x), half_sinc * theta[0], half_sinc * theta[1], half_sinc * theta[2]};
    imu_q30_t out[4];
    int i;
    imu_quat_mul(q, dq, out);
    for (i = 0; i < 4; ++i) {
        q[i] = out[i];
    }
    imu_quat_normalize(q);
}

void imu_quat_from_rotation(imu_q30_t q[4], const imu_q30_t theta[3])
{
    q[0] = 1.0;
    q[1] = q[2] = q[3] = 0.0;
    imu_quat_integrate(q, theta);
}

void imu_quat_turn(imu_q30_t q[4], const imu_q30_t theta[3])
{
    const double sum = theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2];
    if (sum < 1.0 / 4096.0) { /* the fixed build's TURN_SERIES_LIMIT */
        const double step[4] = {1.0 - sum / 8.0, 0.5 * theta[0], 0.5 * theta[1], 0.5 * theta[2]};
        imu_q30_t out[4];
        int i;
        imu_quat_mul(q, step, out);
        for (i = 0; i < 4; ++i) {
            q[i] = out[i];
        }
        return;
    }
    imu_quat_integrate(q, theta);
}

void imu_quat_matrix_row(const imu_q30_t q[4], int row, imu_q30_t out[3])
{
    switch (row) {
    case 0:
        out[0] = 1.0 - 2.0 * (q[2] * q[2] + q[3] * q[3]);
        out[1] = 2.0 * (q[1] * q[2] - q[0] * q[3]);
        out[2] = 2.0 * (q[1] * q[3] + q[0] * q[2]);
        break;
    case 1:
        out[0] = 2.0 * (q[1] * q[2] + q[0] * q[3]);
        out[1] = 1.0 - 2.0 * (q[1] * q[1] + q[3] * q[3]);
        out[2] = 2.0 * (q[2] * q[3] - q[0] * q[1]);
        break;
    default:
        out[0] = 2.0 * (q[1] * q[3] - q[0] * q[2]);
        out[1] = 2.0 * (q[2] * q[3] + q[0] * q[1]);
        out[2] = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]);
        break;
    }
}

void imu_quat_y_axis(const imu_q30_t q[4], imu_q30_t out[3])
{
    out[0] = 2.0 * (q[1] * q[2] - q[0] * q[3]);
    out[1] = 1.0 - 2.0 * (q[1] * q[1] + q[3] * q[3]);
    out[2] = 2.0 * (q[2] * q[3] + q[0] * q[1]);
}

#endif

/* ---- Shared formulas: identical source for both builds below this line. ---- */

void imu_vec3_cross(const imu_q30_t a[3], const imu_q30_t b[3], imu_q30_t out[3])
{
    /* Differences of two Q30 products; |a x b| <= |a||b| <= 1. */
    out[0] = IMU_SUB(IMU_MUL(a[1], b[2], 30), IMU_MUL(a[2], b[1], 30));
    out[1] = IMU_SUB(IMU_MUL(a[2], b[0], 30), IMU_MUL(a[0], b[2], 30));
    out[2] = IMU_SUB(IMU_MUL(a[0], b[1], 30), IMU_MUL(a[1], b[0], 30));
}

void imu_vec3_turn_back(imu_real_t v[3], const imu_q30_t theta[3])
{
    const imu_real_t c0 = IMU_SUB(IMU_MUL(theta[1], v[2], 30), IMU_MUL(theta[2], v[1], 30));
    const imu_real_t c1 = IMU_SUB(IMU_MUL(theta[2], v[0], 30), IMU_MUL(theta[0], v[2], 30));
    const imu_real_t c2 = IMU_SUB(IMU_MUL(theta[0], v[1], 30), IMU_MUL(theta[1], v[0], 30));
    v[0] = IMU_SUB(v[0], c0);
    v[1] = IMU_SUB(v[1], c1);
    v[2] = IMU_SUB(v[2], c2);
}

void imu_quat_mul(const imu_q30_t a[4], const imu_q30_t b[4], imu_q30_t out[4])
{
    /* Each output component is bounded by |a||b| (near 1), but partial sums of the
     * four products may not be: they are summed exactly in int64 and rounded once. */
#ifdef IMU_FIXED
    const int64_t w = (int64_t)a[0] * b[0] - (int64_t)a[1] * b[1] - (int64_t)a[2] * b[2] - (int64_t)a[3] * b[3];
    const int64_t x = (int64_t)a[0] * b[1] + (int64_t)a[1] * b[0] + (int64_t)a[2] * b[3] - (int64_t)a[3] * b[2];
    const int64_t y = (int64_t)a[0] * b[2] - (int64_t)a[1] * b[3] + (int64_t)a[2] * b[0] + (int64_t)a[3] * b[1];
    const int64_t z = (int64_t)a[0] * b[3] + (int64_t)a[1] * b[2] - (int64_t)a[2] * b[1] + (int64_t)a[3] * b[0];
    out[0] = (imu_q30_t)imu_rshift_round64(w, 30);
    out[1] = (imu_q30_t)imu_rshift_round64(x, 30);
    out[2] = (imu_q30_t)imu_rshift_round64(y, 30);
    out[3] = (imu_q30_t)imu_rshift_round64(z, 30);
#else
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
#endif
}

void imu_quat_rotation(const imu_q30_t q[4], imu_rotation_t *r)
{
    int i;
    for (i = 0; i < 3; ++i) {
        imu_quat_matrix_row(q, i, r->row[i]);
    }
}

void imu_rotation_apply(const imu_rotation_t *r, const imu_real_t v[3], imu_real_t out[3])
{
    int i;
    for (i = 0; i < 3; ++i) {
        const imu_q30_t *row = r->row[i];
        out[i] = IMU_ADD(IMU_ADD(IMU_MUL(row[0], v[0], 30), IMU_MUL(row[1], v[1], 30)), IMU_MUL(row[2], v[2], 30));
    }
}

/** imu_quat_to_euler_axes, inline in both public functions (a get converts every call). */
static inline void euler_and_axes(const imu_q30_t q[4], imu_angle_t euler[3], imu_euler_axes_t *axes)
{
    const imu_q30_t *up = axes->up, *y = axes->y;
    imu_quat_matrix_row(q, 2, axes->up);
    imu_quat_y_axis(q, axes->y);
    axes->cos_pitch = imu_hypot(y[0], y[1]);
    euler[0] = imu_atan2(-up[0], up[2]);
    euler[1] = imu_atan2(y[2], axes->cos_pitch);
    euler[2] = imu_atan2(y[0], y[1]);
}

void imu_quat_to_euler_axes(const imu_q30_t q[4], imu_angle_t euler[3], imu_euler_axes_t *axes)
{
    euler_and_axes(q, euler, axes);
}

void imu_quat_to_euler(const imu_q30_t q[4], imu_angle_t euler[3])
{
    imu_euler_axes_t axes;
    euler_and_axes(q, euler, &axes);
}

void imu_euler_to_quat(const imu_angle_t euler[3], imu_q30_t q[4])
{
    /* q = qz(-heading) (x) qx(pitch) (x) qy(roll), each an axis rotation by half angles. */
    imu_q30_t sr, cr, sp, cp, sh, ch;
    imu_q30_t qz[4], qx[4], qy[4], t[4];
    imu_sincos(IMU_HALF(euler[0]), &sr, &cr);
    imu_sincos(IMU_HALF(euler[1]), &sp, &cp);
    imu_sincos(IMU_HALF(euler[2]), &sh, &ch);
    qz[0] = ch;
    qz[1] = 0;
    qz[2] = 0;
    qz[3] = -sh;
    qx[0] = cp;
    qx[1] = sp;
    qx[2] = 0;
    qx[3] = 0;
    qy[0] = cr;
    qy[1] = 0;
    qy[2] = sr;
    qy[3] = 0;
    imu_quat_mul(qz, qx, t);
    imu_quat_mul(t, qy, q);
    imu_quat_normalize(q);
}

int imu_tilt_from_acc(const imu_real_t acc[3], imu_angle_t *roll, imu_angle_t *pitch)
{
    if (acc[0] == 0 && acc[1] == 0 && acc[2] == 0) {
        return 0;
    }
    /* Level reading is (-cos(p) sin(r), sin(p), cos(p) cos(r)) * g. */
    *roll = imu_atan2(-acc[0], acc[2]);
    *pitch = imu_atan2(acc[1], imu_hypot(acc[0], acc[2]));
    return 1;
}

imu_angle_t imu_heading_from_mag(const imu_real_t mag[3], imu_angle_t roll, imu_angle_t pitch)
{
    imu_q30_t sr, cr, sp, cp;
    imu_sincos(roll, &sr, &cr);
    imu_sincos(pitch, &sp, &cp);
    return imu_heading_from_mag_tilt(mag, sr, cr, sp, cp);
}

imu_angle_t imu_heading_from_mag_tilt(const imu_real_t mag[3], imu_q30_t sr, imu_q30_t cr, imu_q30_t sp, imu_q30_t cp)
{
    /* Horizontal field h = Rx(pitch) Ry(roll) m; heading = atan2(-h_x, h_y), which does not
     * depend on the field's scale. */
    imu_real_t m[3];
    imu_real_t w, hx, hy;
    int i;
    if (mag[0] == 0 && mag[1] == 0 && mag[2] == 0) {
        return 0;
    }
#ifdef IMU_FIXED
    {
        /* The largest component scaled by a power of two into [2^29, 2^30): |m| stays
         * below sqrt(3) 2^30 < 2^31, and so do h_x, h_y and w (rotations of m by the
         * unit (cr, sr) and (cp, sp)), with every product rounded to Q30 of m. */
        uint32_t largest = 0;
        int shift;
        for (i = 0; i < 3; ++i) {
            const uint32_t a = mag[i] < 0 ? (uint32_t)(-(int64_t)mag[i]) : (uint32_t)mag[i];
            largest = a > largest ? a : largest;
        }
        shift = imu_clz32(largest) - 2; /* 30 - bit length */
        for (i = 0; i < 3; ++i) {
            m[i] = shift >= 0 ? IMU_NARROW((int64_t)mag[i] * ((int64_t)1 << shift)) : IMU_SHR(mag[i], -shift);
        }
    }
#else
    for (i = 0; i < 3; ++i) {
        m[i] = mag[i];
    }
#endif
    hx = IMU_ADD(IMU_MUL(cr, m[0], 30), IMU_MUL(sr, m[2], 30));
    w = IMU_SUB(IMU_MUL(cr, m[2], 30), IMU_MUL(sr, m[0], 30));
    hy = IMU_SUB(IMU_MUL(cp, m[1], 30), IMU_MUL(sp, w, 30));
    return imu_atan2(-hx, hy);
}

imu_q30_t imu_lowpass_noise_share(imu_q30_t alpha, uint32_t *sat)
{
    /* v <- (1 - alpha)^2 v + alpha^2 settles at alpha^2 / (1 - (1 - alpha)^2), written
     * (alpha / 2) / (1 - alpha / 2): 2 is beyond Q30. */
    const imu_q30_t half_alpha = IMU_HALF(alpha);
    return IMU_DIV_SAT(half_alpha, IMU_SUB(IMU_ONE_Q30, half_alpha), 30, sat);
}

imu_q30_t imu_deviation_weight(imu_real_t deviation, imu_real_t tolerance, uint32_t *sat)
{
    imu_q30_t inv; /* 1 / (1 + (deviation / tolerance)^2) = t^2 / (t^2 + d^2), Q30, <= 1 */
    if (deviation < 0) {
        deviation = IMU_NEG_SAT(deviation, sat);
    }
    if (deviation >= IMU_MUL(tolerance, IMU_QCONST(16.0, 24), 24)) { /* tolerance < 2: 16 x < 2^29 */
        return 0;
    }
#ifdef IMU_FIXED
    {
        /* t^2 (Q48, below 2^50, at least 1) and t^2 + d^2 (below 257 t^2 < 2^59) brought
         * to 31 bits by one shift, each rounded (2^-31 relative: a truncation would bias
         * the weight against the float build's), then one 64-by-32-bit division, rounded:
         * t^2 2^30 / (t^2 + d^2) <= 2^30 */
        const uint64_t t2 = (uint64_t)((int64_t)tolerance * tolerance);
        const uint64_t den = t2 + (uint64_t)((int64_t)deviation * deviation);
        const int down = imu_bit_length64(den) - 31;
        const uint32_t den31 = (uint32_t)(down > 0 ? (den + ((uint64_t)1 << (down - 1))) >> down : den << -down);
        const uint32_t t2_31 = (uint32_t)(down > 0 ? (t2 + ((uint64_t)1 << (down - 1))) >> down : t2 << -down);
        inv = (imu_q30_t)imu_udiv64_32(((uint64_t)t2_31 << 30) + (den31 >> 1), den31);
    }
#else
    inv = tolerance * tolerance / (tolerance * tolerance + deviation * deviation);
#endif
    return IMU_MUL(inv, inv, 30);
}

imu_angle_t imu_field_dip(const imu_q30_t earth[3], imu_q30_t *horizontal)
{
    *horizontal = imu_hypot(earth[0], earth[1]);
    return imu_atan2(-earth[2], *horizontal);
}

imu_q30_t imu_field_weight(imu_real_t norm, imu_real_t ref_norm, imu_angle_t dip, imu_angle_t ref_dip,
                           imu_real_t norm_tolerance, imu_real_t dip_tolerance, imu_q30_t *w_norm, uint32_t *sat)
{
    /* |m| / ref beyond 64 is far outside any tolerance (and the Q24 ratio's range). */
    if (IMU_MUL(norm, IMU_QCONST(1.0 / 64.0, 30), 30) >= ref_norm) {
        *w_norm = 0;
        return 0;
    }
    /* Norm deviation |m| / ref - 1 (Q16 / Q16 -> Q24) and dip deviation (Q29 -> Q24). */
    *w_norm = imu_deviation_weight(IMU_SUB(IMU_DIV_SAT(norm, ref_norm, 24, sat), IMU_QCONST(1.0, 24)), norm_tolerance,
                                   sat);
    return IMU_MUL(*w_norm, imu_deviation_weight(IMU_SHR(imu_angle_diff(dip, ref_dip), 5), dip_tolerance, sat), 30);
}

void imu_field_trust_reset(imu_field_trust_t *t)
{
    t->trusted = 0;
    t->held = 0;
}

void imu_field_trust_confirm(imu_field_trust_t *t, int32_t steps, int32_t limit)
{
    if (t->trusted < limit) {
        t->trusted += steps;
    }
    t->held = 0;
}

void imu_field_trust_drop(imu_field_trust_t *t)
{
    t->held = 0;
}

int imu_field_trust_hold(imu_field_trust_t *t, int32_t steps, int32_t minimum)
{
    t->held += steps;
    if (t->held < minimum || t->held <= t->trusted) {
        return 0;
    }
    t->trusted = t->held;
    t->held = 0;
    return 1;
}
