/**
 * @file imu_arith.h
 * @brief The arithmetic layer: one filter source, two builds.
 *
 * Every filter in firmware/core is written once against the types and macros of
 * this header. Compiled with `IMU_FIXED` the types are `int32_t` holding the Q
 * format named on the type and the macros are integer operations (this is the
 * firmware build). Compiled with `IMU_FLOAT` the types are `double` holding the
 * real value and the macros are plain floating-point operations (the float twin,
 * the reference model). Q formats are therefore annotations in the float build:
 * `IMU_MUL(a, b, s)` is `a * b` there and `(a * b) >> s` (rounded) in fixed point.
 *
 * Q formats (fixed build, all `int32_t`, "m.n" = sign+m integer bits, n fraction):
 *  - imu_q30_t   2.30   dimensionless: quaternion and unit-vector components,
 *                       sines, cosines, gains in [0, 2), time step in s
 *  - imu_angle_t 3.29   angle in rad, range +-4 (covers +-pi)
 *  - imu_rate_t  8.24   angular rate in rad/s, range +-128 rad/s
 *  - imu_q16_t   16.16  settings and physical values near one: gains in 1/s,
 *                       acceleration in m/s^2, magnetic field in uT, rates in Hz
 *  - imu_real_t  int32  any other Q format, named where the value is declared
 *  - imu_wide_t  int64  exact products and their sums, before rounding back
 *
 * Rounding: every right shift of a product rounds to nearest (ties toward +inf).
 * Overflow: plain macros (IMU_MUL, IMU_ADD) require the caller to prove the bound
 * (each use says why it holds); the `_SAT` variants saturate to the int32 range
 * and count the event in a caller-supplied counter. In the float build the
 * saturating variants do not clamp (double has the range) and count nothing.
 *
 * Right shifts of negative values and int64 products are used; both are
 * implementation-defined/defined on every compiler we target (arithmetic shift).
 * Left shifts of negative values are never used (undefined behaviour): scaling up
 * multiplies by a power of two instead.
 *
 * Checked narrowing (debug builds of the fixed build only): with
 * `-DIMU_CHECK_NARROWING` every narrowing of a 64-bit value to int32 that this
 * layer performs without saturation (imu_mul / IMU_MUL, IMU_SHR, IMU_HALF,
 * IMU_TO_INT, IMU_MUL_TO_INT, IMU_NARROW, and the plain IMU_ADD / IMU_SUB, which
 * are then computed in int64) checks that the value fits int32; when it does not,
 * it calls imu_narrowing_failed() with the file and line of the call, the macro's
 * name and the value. The core does not define that function (it has no I/O): the
 * program that builds the checked core does; the test drivers print the report
 * and abort. Should the function return, the value is narrowed as in the unchecked
 * build. Without the macro the definitions below are the unchecked ones, token for
 * token: the firmware's object code is unchanged. The float build ignores it.
 *
 * IMU_NARROW(v): an int64 value the caller has proven to fit, as int32. Use it
 * instead of a raw (int32_t) cast so that the checked build verifies the proof.
 */
#ifndef IMU_ARITH_H
#define IMU_ARITH_H

#include <stdint.h>

#if defined(IMU_FIXED) && defined(IMU_FLOAT)
#error "define exactly one of IMU_FIXED and IMU_FLOAT, not both"
#elif !defined(IMU_FIXED) && !defined(IMU_FLOAT)
#error "define IMU_FIXED (firmware, integer only) or IMU_FLOAT (double twin)"
#endif

#ifdef IMU_FIXED

typedef int32_t imu_q30_t;   /**< 2.30 dimensionless */
typedef int32_t imu_angle_t; /**< 3.29 rad */
typedef int32_t imu_rate_t;  /**< 8.24 rad/s */
typedef int32_t imu_q16_t;   /**< 16.16 */
typedef int32_t imu_real_t;  /**< Q format written where the value is declared */
typedef int64_t imu_wide_t;  /**< products and sums of products before rounding (Q written at use) */

/** Fraction bits of each format (used to convert between formats). */
#define IMU_Q30 30
#define IMU_QANGLE 29
#define IMU_QRATE 24
#define IMU_Q16 16

/** Compile-time constant x (a real literal) in Q`q`: folded by the compiler. */
#define IMU_QCONST(x, q) ((int32_t)((x) * (double)(1LL << (q)) + ((x) >= 0 ? 0.5 : -0.5)))

/** int32 saturation of an int64 value; increments *sat when clamping. */
static inline int32_t imu_sat32(int64_t v, uint32_t *sat)
{
    if ((int32_t)(v >> 32) == ((int32_t)v >> 31)) {
        return (int32_t)v; /* fits: the high word is the low word's sign (one compare on 32-bit cores) */
    }
    if (v > INT32_MAX) {
        ++*sat;
        return INT32_MAX;
    }
    if (v < INT32_MIN) {
        ++*sat;
        return INT32_MIN;
    }
    return (int32_t)v;
}

/** a + b of two int32 values, saturated; increments *sat when clamping. The overflow test
 *  of a 32-bit addition (GCC's and Clang's builtin: the flags of one add on a 32-bit
 *  core) where imu_sat32 of the 64-bit sum needs a 64-bit add and a compare: the same
 *  result. An overflow has b's sign. */
static inline int32_t imu_add_sat32(int32_t a, int32_t b, uint32_t *sat)
{
    int32_t r;
    if (__builtin_add_overflow(a, b, &r)) {
        ++*sat;
        return b < 0 ? INT32_MIN : INT32_MAX;
    }
    return r;
}

/** a - b of two int32 values, saturated (imu_add_sat32); an overflow has the sign of -b. */
static inline int32_t imu_sub_sat32(int32_t a, int32_t b, uint32_t *sat)
{
    int32_t r;
    if (__builtin_sub_overflow(a, b, &r)) {
        ++*sat;
        return b > 0 ? INT32_MIN : INT32_MAX;
    }
    return r;
}

/** (v >> s) rounded to nearest for s in [1, 62]. */
static inline int64_t imu_rshift_round64(int64_t v, int s)
{
    return (v + ((int64_t)1 << (s - 1))) >> s;
}

/** Leading zero bits of v != 0 (GCC and Clang: the Cortex-M4's CLZ instruction). */
static inline int imu_clz32(uint32_t v)
{
#if defined(__GNUC__)
    return __builtin_clz(v);
#else
    int n = 0;
    int step;
    for (step = 16; step > 0; step >>= 1) {
        if (v < ((uint32_t)1 << (32 - step))) {
            n += step;
            v <<= step;
        }
    }
    return n;
#endif
}

/** Number of significant bits of v (0 for v = 0). GCC and Clang count the leading
 *  zeros in one instruction where the target has one (CLZ on the Cortex-M4: the bit
 *  search below costs some 30 instructions); other compilers take the search. */
static inline int imu_bit_length64(uint64_t v)
{
#if defined(__GNUC__)
    return v == 0 ? 0 : 64 - __builtin_clzll(v);
#else
    int n = 0;
    int step;
    for (step = 32; step > 0; step >>= 1) {
        if ((v >> step) != 0) {
            v >>= step;
            n += step;
        }
    }
    return n + (int)v;
#endif
}

/**
 * One 16-bit digit of imu_udiv64_32: floor((top 2^16 + next) / v) for top 2^16 + next < v
 * 2^16, next < 2^16 and v = vn1 2^16 + vn0 normalised (vn1 >= 2^15). Estimated from
 * top / vn1, at most two too large, and corrected against vn0 before use.
 */
static inline uint32_t imu_udiv_digit(uint32_t top, uint32_t next, uint32_t vn1, uint32_t vn0)
{
    const uint32_t b = (uint32_t)1 << 16;
    uint32_t q = top / vn1;
    uint32_t rhat = top - q * vn1;
    /* q * vn0 only once q < 2^16; b rhat + next below 2^32 while rhat < 2^16. */
    while (q >= b || q * vn0 > b * rhat + next) {
        --q;
        rhat += vn1;
        if (rhat >= b) {
            break;
        }
    }
    return q;
}

/**
 * floor(u / v) for v > 0 and u / 2^32 < v (the quotient fits 32 bits), exact, without a
 * 64-bit division: the Cortex-M4 divides 32 by 32 bits in one instruction, 64 bits only
 * in a library routine (__aeabi_uldivmod, 60 to 100 instructions). Long division in
 * base 2^16 after normalising v to [2^31, 2^32) (Knuth's algorithm D, as Hacker's
 * Delight's divlu), two digits of imu_udiv_digit. About 35 instructions.
 */
static inline uint32_t imu_udiv64_32(uint64_t u, uint32_t v)
{
    const int s = imu_clz32(v);
    const uint64_t un = u << s; /* u < v 2^32: below 2^64 after the shift */
    const uint32_t un32 = (uint32_t)(un >> 32);
    const uint32_t un1 = (uint32_t)un >> 16;
    const uint32_t un0 = (uint32_t)un & 0xFFFFu;
    uint32_t q1, rem;
    v <<= s;
    q1 = imu_udiv_digit(un32, un1, v >> 16, v & 0xFFFFu);
    /* the remainder is below v: the 48-bit terms never wrap (no modular arithmetic,
     * which clang's -fsanitize=integer reports) */
    rem = (uint32_t)(((uint64_t)un32 << 16) + un1 - (uint64_t)q1 * v);
    return q1 * ((uint32_t)1 << 16) + imu_udiv_digit(rem, un0, v >> 16, v & 0xFFFFu);
}

/** |v| of an int64 above INT64_MIN, as uint64. */
static inline uint64_t imu_abs64(int64_t v)
{
    return v < 0 ? (uint64_t)(-v) : (uint64_t)v;
}

/** floor(u / v) for v > 0, any u < 2^64, saturated to 2^32 (any quotient beyond int32). */
static inline int64_t imu_udiv_or_big(uint64_t u, uint32_t v)
{
    return (u >> 32) >= v ? (int64_t)1 << 32 : (int64_t)imu_udiv64_32(u, v);
}

/** a*b >> s, rounded. Caller guarantees the result fits in int32. */
static inline int32_t imu_mul(int32_t a, int32_t b, int s)
{
    return (int32_t)imu_rshift_round64((int64_t)a * b, s);
}

/** a*b >> s, rounded and saturated. */
static inline int32_t imu_mul_sat(int32_t a, int32_t b, int s, uint32_t *sat)
{
    return imu_sat32(imu_rshift_round64((int64_t)a * b, s), sat);
}

/** a * 2^s / b, truncated toward zero and saturated; b != 0 required (callers check).
 *  |a| * 2^s must stay below 2^63: s <= 31 for any int32 a. */
static inline int32_t imu_div_sat(int32_t a, int32_t b, int s, uint32_t *sat)
{
    /* Truncation toward zero: the quotient of the magnitudes, signed (imu_udiv_or_big). */
    const int64_t num = (int64_t)a * ((int64_t)1 << s);
    const int64_t q = imu_udiv_or_big(imu_abs64(num), (uint32_t)imu_abs64(b));
    return imu_sat32((num < 0) != (b < 0) ? -q : q, sat);
}

/** (v + *residual) >> s, rounded and saturated, with the rounding error left in
 *  *residual for the next call (error feedback): a value added every sample then
 *  sums exactly, where rounding it alone would add the same error every time a
 *  value repeats, and drift. |v| < 2^62, s in [1, 62]; a saturated result drops
 *  the residual. */
static inline int32_t imu_wshr_feedback_sat(int64_t v, int s, int64_t *residual, uint32_t *sat)
{
    const int64_t total = v + *residual;
    const int64_t rounded = imu_rshift_round64(total, s);
    if (rounded > INT32_MAX || rounded < INT32_MIN) {
        *residual = 0;
        return imu_sat32(rounded, sat);
    }
    *residual = total - rounded * ((int64_t)1 << s);
    return (int32_t)rounded;
}

#define IMU_MUL_SAT(a, b, s, sat) imu_mul_sat((a), (b), (s), (sat))
#define IMU_DIV_SAT(a, b, s, sat) imu_div_sat((a), (b), (s), (sat))
#define IMU_WSHR_FEEDBACK_SAT(v, s, residual, sat) imu_wshr_feedback_sat((v), (s), (residual), (sat))
#define IMU_NEG_SAT(a, sat) imu_sat32(-(int64_t)(a), (sat))
/** Add s fraction bits (Qn to Q(n+s)), saturated. */
#define IMU_SHL_SAT(a, s, sat) imu_sat32((int64_t)(a) * ((int64_t)1 << (s)), (sat))
/** Integer value (counts, sample numbers) to a real in Q`q`; saturated. */
#define IMU_FROM_INT_SAT(i, q, sat) imu_sat32((int64_t)(i) * ((int64_t)1 << (q)), (sat))

#ifndef IMU_CHECK_NARROWING

#define IMU_MUL(a, b, s) imu_mul((a), (b), (s))
#define IMU_ADD(a, b) ((a) + (b))
#define IMU_SUB(a, b) ((a) - (b))
/** Drop s fraction bits (Qn to Q(n-s)), rounded. */
#define IMU_SHR(a, s) ((int32_t)imu_rshift_round64((a), (s)))
/** Half of a value, same format, rounded. */
#define IMU_HALF(a) ((int32_t)imu_rshift_round64((a), 1))
/** A real in Q`q` to the nearest integer. */
#define IMU_TO_INT(a, q) ((int32_t)imu_rshift_round64((a), (q)))
/** Nearest integer to the product of reals a and b whose Q formats add up to q (result below 2^31). */
#define IMU_MUL_TO_INT(a, b, q) ((int32_t)imu_rshift_round64((int64_t)(a) * (b), (q)))
/** An int64 value proven (at the call) to fit int32, as int32. */
#define IMU_NARROW(v) ((int32_t)(v))
/** Saturated sum and difference of two int32 reals of one Q format. */
#define IMU_ADD_SAT(a, b, sat) imu_add_sat32((a), (b), (sat))
#define IMU_SUB_SAT(a, b, sat) imu_sub_sat32((a), (b), (sat))

#else /* IMU_CHECK_NARROWING: the same operations, each narrowing checked */

/** Report of a narrowing whose value does not fit int32: defined by the program
 *  that builds the checked core (see the file comment). */
void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value);

/** v as int32, reporting (file, line, what) when it does not fit. */
static inline int32_t imu_narrow_at(int64_t v, const char *file, int line, const char *what)
{
    if (v > INT32_MAX || v < INT32_MIN) {
        imu_narrowing_failed(file, line, what, v);
    }
    return (int32_t)v;
}

/** imu_mul, checked. */
static inline int32_t imu_mul_at(int32_t a, int32_t b, int s, const char *file, int line)
{
    return imu_narrow_at(imu_rshift_round64((int64_t)a * b, s), file, line, "IMU_MUL");
}

/* Direct calls of imu_mul() are checked too: from here on the name is a macro. */
#define imu_mul(a, b, s) imu_mul_at((a), (b), (s), __FILE__, __LINE__)
#define IMU_MUL(a, b, s) imu_mul_at((a), (b), (s), __FILE__, __LINE__)
#define IMU_ADD(a, b) imu_narrow_at((int64_t)(a) + (b), __FILE__, __LINE__, "IMU_ADD")
#define IMU_SUB(a, b) imu_narrow_at((int64_t)(a) - (b), __FILE__, __LINE__, "IMU_SUB")
#define IMU_SHR(a, s) imu_narrow_at(imu_rshift_round64((a), (s)), __FILE__, __LINE__, "IMU_SHR")
#define IMU_HALF(a) imu_narrow_at(imu_rshift_round64((a), 1), __FILE__, __LINE__, "IMU_HALF")
#define IMU_TO_INT(a, q) imu_narrow_at(imu_rshift_round64((a), (q)), __FILE__, __LINE__, "IMU_TO_INT")
#define IMU_MUL_TO_INT(a, b, q) \
    imu_narrow_at(imu_rshift_round64((int64_t)(a) * (b), (q)), __FILE__, __LINE__, "IMU_MUL_TO_INT")
#define IMU_NARROW(v) imu_narrow_at((v), __FILE__, __LINE__, "IMU_NARROW")
/* Their operands are int32: a wide one would be cut to 32 bits before the saturation. */
#define IMU_ADD_SAT(a, b, sat)                                                                                   \
    imu_add_sat32(imu_narrow_at((a), __FILE__, __LINE__, "IMU_ADD_SAT"),                                       \
                  imu_narrow_at((b), __FILE__, __LINE__, "IMU_ADD_SAT"), (sat))
#define IMU_SUB_SAT(a, b, sat)                                                                                   \
    imu_sub_sat32(imu_narrow_at((a), __FILE__, __LINE__, "IMU_SUB_SAT"),                                       \
                  imu_narrow_at((b), __FILE__, __LINE__, "IMU_SUB_SAT"), (sat))

#endif /* IMU_CHECK_NARROWING */

/** Exact product of two int32 reals as a wide value (Q formats add). */
#define IMU_WMUL(a, b) ((int64_t)(a) * (b))
/** Wide value with s fewer fraction bits, rounded. */
#define IMU_WSHR(v, s) imu_rshift_round64((v), (s))
/** Wide value to int32 (same Q format), saturated. */
#define IMU_WIDE_SAT(v, sat) imu_sat32((v), (sat))

#else /* IMU_FLOAT */

typedef double imu_q30_t;
typedef double imu_angle_t;
typedef double imu_rate_t;
typedef double imu_q16_t;
typedef double imu_real_t;
typedef double imu_wide_t;

#define IMU_QCONST(x, q) ((double)(x))
#define IMU_MUL(a, b, s) ((a) * (b))
#define IMU_MUL_SAT(a, b, s, sat) ((void)(sat), (a) * (b))
#define IMU_DIV_SAT(a, b, s, sat) ((void)(sat), (a) / (b))
#define IMU_WSHR_FEEDBACK_SAT(v, s, residual, sat) ((void)(residual), (void)(sat), (v))
#define IMU_ADD(a, b) ((a) + (b))
#define IMU_SUB(a, b) ((a) - (b))
#define IMU_ADD_SAT(a, b, sat) ((void)(sat), (a) + (b))
#define IMU_SUB_SAT(a, b, sat) ((void)(sat), (a) - (b))
#define IMU_NEG_SAT(a, sat) ((void)(sat), -(a))
#define IMU_SHR(a, s) (a)
#define IMU_HALF(a) (0.5 * (a))
#define IMU_SHL_SAT(a, s, sat) ((void)(sat), (a))
#define IMU_FROM_INT_SAT(i, q, sat) ((void)(sat), (double)(i))
#define IMU_TO_INT(a, q) ((int32_t)((a) >= 0 ? (a) + 0.5 : (a) - 0.5))
#define IMU_MUL_TO_INT(a, b, q) IMU_TO_INT((a) * (b), 0)
#define IMU_WMUL(a, b) ((a) * (b))
#define IMU_WSHR(v, s) (v)
#define IMU_WIDE_SAT(v, sat) ((void)(sat), (v))
#define IMU_NARROW(v) (v)

#endif

/** Frequently used constants. */
#define IMU_ONE_Q30 IMU_QCONST(1.0, 30)
#define IMU_PI_ANGLE IMU_QCONST(3.14159265358979323846, 29)
#define IMU_HALF_PI_ANGLE IMU_QCONST(1.57079632679489661923, 29)

#endif /* IMU_ARITH_H */
