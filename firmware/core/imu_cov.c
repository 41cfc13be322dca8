/**
 * @file imu_cov.c
 * @brief Block-floating symmetric covariance (see imu_cov.h).
 *
 * The algorithms below are shared by both builds; only the handful of helpers in
 * the first section differ: in the float build, exponents stay 0, scaling by 2^n
 * is exact and formats are annotations.
 */
#include "imu_cov.h" /* imu_navcov.c includes this file after it, for its own size and names */

/** Index of (i, j), i <= j, in the upper-triangle storage (row by row). */
#define CELL_UPPER(i, j) ((i) * IMU_COV_MAX - (i) * ((i) - 1) / 2 + ((j) - (i)))
#define CELL_OF(i, j) ((i) <= (j) ? CELL_UPPER(i, j) : CELL_UPPER(j, i))

/* The table below is written out for nine states, or sixteen (imu_navcov.c). */
#if IMU_COV_MAX == 9
#define CELL_ROW(i) \
    { CELL_OF(i, 0), CELL_OF(i, 1), CELL_OF(i, 2), CELL_OF(i, 3), CELL_OF(i, 4), \
      CELL_OF(i, 5), CELL_OF(i, 6), CELL_OF(i, 7), CELL_OF(i, 8) }
#define CELL_ROWS \
    CELL_ROW(0), CELL_ROW(1), CELL_ROW(2), CELL_ROW(3), CELL_ROW(4), CELL_ROW(5), CELL_ROW(6), CELL_ROW(7), \
        CELL_ROW(8)
#elif IMU_COV_MAX == 16
#define CELL_ROW(i) \
    { CELL_OF(i, 0), CELL_OF(i, 1), CELL_OF(i, 2), CELL_OF(i, 3), CELL_OF(i, 4), \
      CELL_OF(i, 5), CELL_OF(i, 6), CELL_OF(i, 7), CELL_OF(i, 8), CELL_OF(i, 9), \
      CELL_OF(i, 10), CELL_OF(i, 11), CELL_OF(i, 12), CELL_OF(i, 13), CELL_OF(i, 14), CELL_OF(i, 15) }
#define CELL_ROWS \
    CELL_ROW(0), CELL_ROW(1), CELL_ROW(2), CELL_ROW(3), CELL_ROW(4), CELL_ROW(5), CELL_ROW(6), CELL_ROW(7), \
        CELL_ROW(8), CELL_ROW(9), CELL_ROW(10), CELL_ROW(11), CELL_ROW(12), CELL_ROW(13), CELL_ROW(14), CELL_ROW(15)
#else
#error "imu_cov.c: CELL_INDEX is written out for 9 or 16 states"
#endif

/** Storage index of (i, j) for any i, j: a table, as the covariance loops look it up
 *  for every product (the arithmetic and the swap cost a dozen instructions). */
static const unsigned char CELL_INDEX[IMU_COV_MAX][IMU_COV_MAX] = {CELL_ROWS};

static int cell(int i, int j)
{
    return CELL_INDEX[i][j];
}

static void store_diagonal(imu_cov_t *c, imu_wide_t d[IMU_COV_MAX], uint32_t *sat);

#ifdef IMU_FIXED

#define WIDE_LIMIT ((int64_t)1 << 62)

/** v * 2^n: rounded for n < 0, saturated to +-2^62 for n > 0. */
static inline imu_wide_t wide_ldexp(imu_wide_t v, int n, uint32_t *sat)
{
    /* n < 0: imu_rshift_round64(v, -n) as ((v >> (-n - 1)) + 1) >> 1, the same integer with
     * one variable 64-bit shift instead of two (n varies here); from 32 bits on, that shift
     * is one of the high word ((x + 1) >> 1 written (x >> 1) + (x & 1), which cannot
     * overflow). The longest shifts are tested first: they are the most frequent. */
    if (n <= -33) {
        if (n < -62) {
            return 0;
        }
        {
            const int32_t x = (int32_t)(v >> 32) >> (-n - 33);
            return (x >> 1) + (x & 1);
        }
    }
    if (n < 0) {
        return ((v >> (-n - 1)) + 1) >> 1;
    }
    if (n == 0) {
        return v; /* unmoved exponents */
    }
    if (n > 62 || v > (WIDE_LIMIT >> n) || v < -(WIDE_LIMIT >> n)) {
        if (v == 0) {
            return 0;
        }
        ++*sat;
        return v > 0 ? WIDE_LIMIT : -WIDE_LIMIT;
    }
    return v * ((int64_t)1 << n);
}

/** wide_ldexp(v, n) of an int32 v, the same integer: 32-bit shifts for n < 0, and no saturation
 *  test for n < 32, where |v| 2^n stays below 2^62. */
static inline imu_wide_t real_ldexp(int32_t v, int n, uint32_t *sat)
{
    if (n < 0) {
        if (n <= -32) {
            return 0; /* |v| 2^n <= 1/2, which rounds (ties up) to 0 */
        }
        {
            const int32_t t = v >> (-n - 1);
            return (t >> 1) + (t & 1); /* (t + 1) >> 1 without its overflow */
        }
    }
    if (n < 32) {
        return (imu_wide_t)v * ((int64_t)1 << n); /* below 2^62 */
    }
    return wide_ldexp(v, n, sat);
}

static imu_wide_t wide_abs(imu_wide_t v)
{
    return v < 0 ? -v : v;
}

/** Right shift that brings a magnitude below 2^bits (0 when it already is). */
static int headroom(imu_wide_t magnitude, int bits)
{
    const int excess = imu_bit_length64((uint64_t)magnitude) - bits;
    return excess > 0 ? excess : 0;
}

/** v 2^-k rounded (wide_ldexp) as an int32, for |v| < 2^(31 + k), k >= 0 (headroom(., 31)
 *  gives such a k): the rounding can reach +2^31 exactly, which becomes INT32_MAX (one unit
 *  in 2^31). For k < 32, in 32-bit operations: the quotient's low word plus the bit below. */
static imu_real_t shifted_int32(imu_wide_t v, int k, uint32_t *sat)
{
    if (k == 0) {
        return (imu_real_t)v;
    }
    if (k < 32) {
        /* floor(v 2^-k), an int32: the low word's bits from k up, the high word's low k bits above them */
        const uint32_t low = (uint32_t)v, high_bits = (uint32_t)(v >> 32) & (((uint32_t)1 << k) - 1u);
        const int32_t quotient = (int32_t)((low >> k) | (high_bits << (32 - k)));
        return quotient == INT32_MAX ? quotient : quotient + (int32_t)(low >> (k - 1) & 1u);
    }
    {
        const imu_wide_t r = wide_ldexp(v, -k, sat);
        return (imu_real_t)(r > INT32_MAX ? INT32_MAX : r);
    }
}

/** 1 when a diagonal mantissa lies in [2^28, 2^30), where it stays: one unsigned comparison
 *  tests both bounds. */
static inline int normalised_diagonal(imu_wide_t d)
{
    return (uint64_t)(d - ((int64_t)1 << 28)) < ((uint64_t)3 << 28);
}

/**
 * The exponent change of each state that brings its diagonal mantissa d_i (Q30 in the
 * old exponents) into [2^28, 2^30): d_i 2^(-2 shift_i). A diagonal that rounding drove
 * to zero or below restarts at the smallest normalised value (counted). Returns
 * non-zero when an exponent moves.
 */
static int diagonal_shifts(const imu_cov_t *c, imu_wide_t d[IMU_COV_MAX], signed char shift[IMU_COV_MAX],
                           uint32_t *sat)
{
    int i, moved = 0;
    for (i = 0; i < c->n; ++i) {
        /* s = ceil((bits - 30) / 2): d * 2^(-2s) in [2^28, 2^30); 0 for the usual d already there */
        if (normalised_diagonal(d[i])) {
            shift[i] = 0;
        } else {
            int excess;
            if (d[i] <= 0) {
                ++*sat; /* rounding destroyed this variance: restart it at the smallest normalised value */
                d[i] = (int64_t)1 << 28;
            }
            excess = imu_bit_length64((uint64_t)d[i]) - 30;
            shift[i] = (signed char)(excess >= 0 ? (excess + 1) / 2 : -((-excess) / 2));
            moved |= shift[i];
        }
    }
    return moved;
}

/** A wide value (Q30 in the old exponents) as an int32 mantissa of exponents that
 *  moved by `down` in all: v 2^-down, rounded and saturated. */
static imu_real_t rescaled(imu_wide_t v, int down, uint32_t *sat)
{
    return imu_sat32(down == 0 ? v : wide_ldexp(v, -down, sat), sat);
}

/** Number of significant bits of |v|, v != 0 (one leading-zero count). */
static int magnitude_bits(int32_t v)
{
    return 32 - imu_clz32((uint32_t)(v < 0 ? -(int64_t)v : v));
}

/** Bits to add to a sum of `count` terms: 2^bits >= count. */
static int count_bits(int count)
{
    int bits = 0;
    while ((1 << bits) < count) {
        ++bits;
    }
    return bits;
}

/** Q30 measurement row scaled by 2^(e_j - E), with E chosen so the largest entry is in
 *  [2^(29 - x), 2^(30 - x)], 2^x at least the number of non-zero entries: a sum of the
 *  products with P~'s entries (below 2^30) stays below 2^60. Out: its entries that are not
 *  zero, hs[t] of the state used[t], and their count; returns E. */
static int scale_row(const imu_cov_t *c, const imu_q30_t h[], imu_q30_t hs[], unsigned char used[], int *used_count,
                     uint32_t *sat)
{
    int big = INT32_MIN;
    int count = 0, kept = 0;
    int j, t;
    for (j = 0; j < c->n; ++j) {
        if (h[j] != 0) {
            const int mag = c->e[j] + magnitude_bits(h[j]) - 30;
            big = mag > big ? mag : big;
            used[count++] = (unsigned char)j;
        }
    }
    if (big == INT32_MIN) {
        big = 0;
    }
    big += count_bits(count);
    for (t = 0; t < count; ++t) {
        const int k = used[t];
        hs[kept] = (imu_q30_t)real_ldexp(h[k], c->e[k] - big, sat);
        if (hs[kept] != 0) {
            used[kept++] = (unsigned char)k;
        }
    }
    *used_count = kept;
    return big;
}

/**
 * Row i of phi in the scaled coordinates, phi~_ik = phi_ik 2^(e_k - e_i), as multipliers
 * row[t] of the columns cols[t] (the row is overwritten, its first `count` entries
 * used) and a row exponent f: phi~_{i,cols[t]} = phi[i][t] 2^-f, |phi[i][t]| <= 2^(31 - x),
 * 2^x >= count. A sum of `count` products of those with P~'s entries (below 2^30) then
 * stays within 2^61 and one with int32 values within 2^62, so the products accumulate
 * without a shift per term. Returns f.
 */
static int scaled_row(const imu_cov_t *c, imu_q30_t row[IMU_COV_MAX], int i, int count,
                      const unsigned char cols[], uint32_t *sat)
{
    int biggest = INT32_MIN; /* |phi~_ik| < 2^(biggest - 30) */
    int f, t;
    for (t = 0; t < count; ++t) {
        const int k = cols[t];
        const int bits = magnitude_bits(row[k]) + c->e[k] - c->e[i];
        biggest = bits > biggest ? bits : biggest;
    }
    f = 61 - count_bits(count) - biggest;
    for (t = 0; t < count; ++t) { /* cols[t] >= t: each entry is read before it is written */
        const int k = cols[t];
        row[t] = (imu_q30_t)real_ldexp(row[k], c->e[k] - c->e[i] - 30 + f, sat);
    }
    return f;
}

/** v = mant * 2^exp with |mant| in [2^29, 2^30) (mant = 0 for v = 0). */
static int32_t normalize_wide(imu_wide_t v, int *exp)
{
    const int bits = imu_bit_length64((uint64_t)(v < 0 ? -v : v));
    *exp = bits - 30;
    return (int32_t)(bits > 30 ? imu_rshift_round64(v, bits - 30) : v * ((int64_t)1 << (30 - bits)));
}

/** a * b / 2^31, rounded: one 32-bit multiply. */
static inline int32_t mul_q31(int32_t a, int32_t b)
{
    return (int32_t)(((int64_t)a * b + ((int64_t)1 << 30)) >> 31);
}

/** v 2^-e as an int32, |v| < 2^(31 + e): a 32-bit shift when e <= 0 (the values of a
 *  measurement's P h are below 2^30), a rounded one otherwise. */
static inline int32_t mantissa31(imu_wide_t v, int e, uint32_t *sat)
{
    if (e <= 0) {
        return (int32_t)v * ((int32_t)1 << -e); /* e >= -30: bit_length(v) >= 1 */
    }
    return shifted_int32(v, e, sat);
}

/** (w / sh) m 2^(2 ce + 1) of a mantissa m (cm_i or om_i) from k_mant 2^scale = w / sh:
 *  |m k_mant| < 2^61 and the result is below 2^31 (apply_update). */
static inline int32_t gain_of(int32_t m, int32_t k_mant, int scale, uint32_t *sat)
{
    return imu_sat32(wide_ldexp((imu_wide_t)m * k_mant, scale, sat), sat);
}

/** The change of P~_ij (Q30) a measurement makes: kc_i cm_j - ko_i om_j, each 2^-31
 *  (ko_i and om are zero unless `mapped`). */
static inline imu_wide_t change(int32_t kc_i, int32_t ko_i, const int32_t cm[], const int32_t om[], int32_t mapped,
                                int j)
{
    return mapped == 0 ? mul_q31(kc_i, cm[j]) : (imu_wide_t)mul_q31(kc_i, cm[j]) - mul_q31(ko_i, om[j]);
}

/**
 * P~ -= (w / sh) (ch ch^T - oh oh^T) and dx_i += (w z / sh) (ch_i - oh_i) 2^(e_i - E) (Q30); cmax is max |ch_i|.
 * ch and oh become 31-bit mantissas cm (in place of ch), om of one exponent ce; kc = (w / sh) cm 2^(2 ce + 1)
 * makes each cell's change kc_i cm_j 2^-31, a 32-bit product: |kc_i| < 2^31, as the
 * change of a variance, (w / sh) ch_i^2 2^-30 <= P~_ii, is below 2^30 (Cauchy-Schwarz).
 * Without a gain map (NULL), oh is only the storage of d.
 */
static void apply_update(imu_cov_t *c, imu_real_t ch[], imu_wide_t cmax, imu_wide_t oh[],
                         const imu_cov_map_t *gain_map, imu_wide_t sh, imu_q30_t w, imu_q30_t z, int big,
                         imu_q30_t dx[], uint32_t *sat)
{
    const int left = gain_map != 0;
    int32_t *const cm = ch;      /* ch as mantissas of 2^ce, below 2^31: in place of ch */
    int32_t om[IMU_COV_MAX];     /* the same for oh (when `left`) */
    int32_t kc[IMU_COV_MAX];     /* (w / sh) cm 2^(2 ce + 1) (gain_of) */
    imu_wide_t *const d = oh;    /* the new diagonal, Q30 in the old exponents: in place of oh */
    signed char shift[IMU_COV_MAX]; /* exponent changes, |shift| <= 17 */
    int32_t mapped = 0;   /* non-zero when a gain map left a part out */
    unsigned whole = 0;   /* bit i: state i wholly left out (oh_i = ch_i: om_i = cm_i, ko_i = kc_i) */
    int split = 1;        /* 1 while each state is wholly left out or wholly corrected (om_i = 0) */
    int normalised = 1;   /* 1 while every new diagonal mantissa is in [2^28, 2^30) */
    int ce, ke, ve, k_exp, v_exp, i, j, k;
    int32_t k_mant, v_mant;
    for (i = 0; left && i < c->n; ++i) {
        const imu_wide_t b = wide_abs(oh[i]);
        cmax = b > cmax ? b : cmax;
    }
    if (cmax == 0) {
        return;
    }
    ce = imu_bit_length64((uint64_t)cmax) - 31; /* cmax 2^-ce in [2^30, 2^31) */
    for (i = 0; left && i < c->n; ++i) {
        om[i] = mantissa31(oh[i], ce, sat);
        mapped |= om[i];
    }
    for (i = 0; left && 3 * i < c->n; ++i) { /* the blocks (the last may be partial) */
        /* (left_out: a block left out wholly has oh = ch, one corrected wholly oh = 0) */
        whole |= gain_map->block[i] == IMU_COV_BLOCK_NONE ? 7u << (3 * i) : 0u;
        split &= gain_map->block[i] != IMU_COV_BLOCK_ALONG;
    }
    {
        /* sh = sn 2^es with sn in [2^30, 2^31) (truncated), so that both quotients are
         * 64-by-32-bit divisions (imu_udiv64_32) of numerators below sn 2^32. */
        const int es = imu_bit_length64((uint64_t)sh) - 31;
        const uint32_t sn = (uint32_t)(es > 0 ? sh >> es : sh * ((int64_t)1 << -es));
        /* w z / sh: (w z (Q60)) >> 30 -> Q30 (|wz| <= 2^31), then (|wz| 2^30) / sn. */
        const imu_wide_t wz = imu_rshift_round64((imu_wide_t)w * z, 30);
        const int64_t v = (int64_t)imu_udiv64_32(imu_abs64(wz) << 30, sn);
        /* w / sh: (w 2^31) / sn = k 2^(-31 + es); w <= 2^30 */
        k_mant = normalize_wide((int64_t)imu_udiv64_32((uint64_t)w << 31, sn), &ke);
        ke -= 31 + es;
        v_mant = normalize_wide(wz < 0 ? -v : v, &ve);
        ve -= 30 + es;
    }
    k_exp = 2 * ce + ke + 1; /* the gains' exponent (gain_of) */
    v_exp = ve + ce - big;   /* the corrections' exponent but for e_i */
    for (i = 0; i < c->n; ++i) {
        /* dx_i = v (cm_i - om_i) 2^(ve + ce + e_i - E) in Q30: v_mant * (cm_i - om_i) < 2^62. */
        imu_wide_t vc;
        int32_t ko_i = 0;
        cm[i] = mantissa31(ch[i], ce, sat);
        vc = IMU_WMUL(v_mant, cm[i]);
        if (mapped != 0) {
            vc = (imu_wide_t)v_mant * ((imu_wide_t)cm[i] - om[i]);
            ko_i = gain_of(om[i], k_mant, k_exp, sat);
        }
        kc[i] = gain_of(cm[i], k_mant, k_exp, sat);
        dx[i] = IMU_ADD_SAT(dx[i], imu_sat32(wide_ldexp(vc, v_exp + c->e[i], sat), sat), sat);
        d[i] = (imu_wide_t)c->p[cell(i, i)] - change(kc[i], ko_i, cm, om, mapped, i);
        normalised &= normalised_diagonal(d[i]); /* (diagonal_shifts' test) */
    }
    if (normalised || diagonal_shifts(c, d, shift, sat) == 0) {
        /* the usual case: no exponent moves, each cell its change saturated (rescaled by 0), in
         * a loop of its own for each kind of update: without a map, with a map whose blocks are
         * corrected wholly or not at all, with one along a vector (mul_q31 of |kc_i| <= 2^31 and
         * |cm_j| < 2^31 is an int32) */
        for (i = 0; i < c->n; ++i) {
            c->p[cell(i, i)] = (int32_t)d[i]; /* in [2^28, 2^30) */
        }
        for (i = 0; mapped == 0 && i < c->n - 1; ++i) {
            for (j = i + 1, k = cell(i, j); j < c->n; ++j, ++k) {
                c->p[k] = IMU_SUB_SAT(c->p[k], mul_q31(kc[i], cm[j]), sat);
            }
        }
        for (i = 0; mapped != 0 && split && i < c->n - 1; ++i) {
            /* kc_i cm_j - ko_i om_j is kc_i cm_j where state i or j is wholly corrected (its
             * ko or om is 0), and 0 where both are wholly left out (ko_i om_j = kc_i cm_j) */
            const unsigned kept = (whole >> i & 1u) != 0 ? whole : 0u;
            for (j = i + 1, k = cell(i, j); j < c->n; ++j, ++k) {
                if ((kept >> j & 1u) == 0) {
                    c->p[k] = IMU_SUB_SAT(c->p[k], mul_q31(kc[i], cm[j]), sat);
                }
            }
        }
        for (i = 0; mapped != 0 && !split && i < c->n - 1; ++i) {
            uint32_t counted_before = 0; /* (ko_i once more: its saturations were counted the first time) */
            const int32_t ko_i = gain_of(om[i], k_mant, k_exp, &counted_before);
            for (j = i + 1, k = cell(i, j); j < c->n; ++j, ++k) {
                c->p[k] = imu_sat32((imu_wide_t)c->p[k] - mul_q31(kc[i], cm[j]) + mul_q31(ko_i, om[j]), sat);
            }
        }
        return;
    }
    for (i = 0; i < c->n; ++i) {
        uint32_t counted_before = 0;
        const int32_t ko_i = mapped != 0 ? gain_of(om[i], k_mant, k_exp, &counted_before) : 0;
        k = cell(i, i);
        c->p[k] = rescaled(d[i], 2 * shift[i], sat);
        for (j = i + 1, ++k; j < c->n; ++j, ++k) {
            c->p[k] = rescaled((imu_wide_t)c->p[k] - change(kc[i], ko_i, cm, om, mapped, j), shift[i] + shift[j], sat);
        }
    }
    for (i = 0; i < c->n; ++i) {
        c->e[i] += shift[i];
    }
}

/** Wide Q60 value back to Q30. */
#define Q60_TO_Q30(v) imu_rshift_round64((v), 30)

/** Exponent that gives a variance (wide, Q`q`, > 0) a mantissa of 29 to 31 bits, so that
 *  the renormalisation keeps all of its bits whatever its size. */
static int32_t exponent_for(imu_wide_t var, int q)
{
    return var > 0 ? (imu_bit_length64((uint64_t)var) - q) / 2 : 0;
}

/** 1 when r 2^shift exceeds the wide range: the measurement's noise dwarfs its
 *  sensitivity (a row of rounding-level entries) and it carries no information. */
static int noise_dwarfs_row(imu_wide_t r, int shift)
{
    return shift > 0 && (shift > 62 || r > (WIDE_LIMIT >> shift));
}

/** Scale state i so that its variance is below 1 (in its units): e_i <= 0 gives
 *  P_ii = p_ii 2^(2 e_i - 30) < 1; row and column scale with it, P stays PSD. */
static void cap_unit_variance(imu_cov_t *c, int i)
{
    if (c->e[i] > 0) {
        c->e[i] = 0;
    }
}

/** v * w for a wide Q30 value v (any size below 2^62) and a Q30 factor w, |w| <= 1. */
static imu_wide_t wide_mul_q30(imu_wide_t v, imu_q30_t w)
{
    const imu_wide_t hi = v / ((int64_t)1 << 30); /* truncated toward zero */
    const imu_wide_t lo = v - hi * ((int64_t)1 << 30);
    return hi * w + imu_rshift_round64(lo * w, 30);
}

#else /* IMU_FLOAT */

/* Every shift in the shared code is a Q-format change or an exponent difference,
 * and exponents stay 0 in this build: both are the identity. */
static imu_wide_t wide_ldexp(imu_wide_t v, int n, uint32_t *sat)
{
    (void)n;
    (void)sat;
    return v;
}

static imu_wide_t real_ldexp(imu_real_t v, int n, uint32_t *sat)
{
    (void)n;
    (void)sat;
    return v;
}

static imu_wide_t wide_abs(imu_wide_t v)
{
    return v < 0 ? -v : v;
}

static int headroom(imu_wide_t magnitude, int bits)
{
    (void)magnitude;
    (void)bits;
    return 0;
}

static imu_real_t shifted_int32(imu_wide_t v, int k, uint32_t *sat)
{
    (void)k;
    (void)sat;
    return v;
}

static int diagonal_shifts(const imu_cov_t *c, imu_wide_t d[IMU_COV_MAX], signed char shift[IMU_COV_MAX],
                           uint32_t *sat)
{
    int i;
    for (i = 0; i < c->n; ++i) {
        if (d[i] <= 0.0) {
            ++*sat;
            d[i] = 1e-30;
        }
        shift[i] = 0;
    }
    return 0;
}

static imu_real_t rescaled(imu_wide_t v, int down, uint32_t *sat)
{
    (void)down;
    (void)sat;
    return v;
}

static int scale_row(const imu_cov_t *c, const imu_q30_t h[], imu_q30_t hs[], unsigned char used[], int *used_count,
                     uint32_t *sat)
{
    int j, count = 0;
    (void)sat;
    for (j = 0; j < c->n; ++j) {
        if (h[j] != 0) {
            hs[count] = h[j];
            used[count++] = (unsigned char)j;
        }
    }
    *used_count = count;
    return 0;
}

static int scaled_row(const imu_cov_t *c, imu_q30_t row[IMU_COV_MAX], int i, int count,
                      const unsigned char cols[], uint32_t *sat)
{
    int t;
    (void)c;
    (void)i;
    (void)sat;
    for (t = 0; t < count; ++t) {
        row[t] = row[cols[t]];
    }
    return 0;
}

static void apply_update(imu_cov_t *c, imu_real_t ch[], imu_wide_t cmax, imu_wide_t oh[],
                         const imu_cov_map_t *gain_map, imu_wide_t sh, imu_q30_t w, imu_q30_t z, int big,
                         imu_q30_t dx[], uint32_t *sat)
{
    imu_wide_t d[IMU_COV_MAX];
    int i, j;
    (void)cmax;
    (void)big;
    for (i = 0; gain_map == 0 && i < c->n; ++i) {
        oh[i] = 0.0; /* nothing left out without a map */
    }
    for (i = 0; i < c->n; ++i) {
        dx[i] += w * z / sh * (ch[i] - oh[i]);
        for (j = i; j < c->n; ++j) {
            c->p[cell(i, j)] -= w / sh * (ch[i] * ch[j] - oh[i] * oh[j]);
        }
        d[i] = c->p[cell(i, i)];
    }
    store_diagonal(c, d, sat);
}

#define Q60_TO_Q30(v) (v)

static int32_t exponent_for(imu_wide_t var, int q)
{
    (void)var;
    (void)q;
    return 0;
}

static int noise_dwarfs_row(imu_wide_t r, int shift)
{
    (void)r;
    (void)shift;
    return 0;
}

/* The same power-of-two scaling as the fixed build's exponent change. */
static void cap_unit_variance(imu_cov_t *c, int i)
{
    int j;
    while (c->p[cell(i, i)] >= 1.0) {
        for (j = 0; j < c->n; ++j) {
            c->p[cell(i, j)] *= j == i ? 0.25 : 0.5;
        }
    }
}

static imu_wide_t wide_mul_q30(imu_wide_t v, imu_q30_t w)
{
    return v * w;
}

#endif

/* ---- Shared algorithms. ---- */

/** Store P~ with the wide diagonal d (Q30 in the old exponents; every other element is
 *  c->p's) in new exponents that bring every diagonal mantissa into [2^28, 2^30)
 *  (diagonal_shifts). */
static void store_diagonal(imu_cov_t *c, imu_wide_t d[IMU_COV_MAX], uint32_t *sat)
{
    signed char shift[IMU_COV_MAX]; /* exponent changes, |shift| <= 17 */
    int i, j, k;
    diagonal_shifts(c, d, shift, sat);
    for (i = 0; i < c->n; ++i) {
        k = cell(i, i);
        c->p[k] = rescaled(d[i], 2 * shift[i], sat);
        for (j = i + 1, ++k; j < c->n; ++j, ++k) {
            c->p[k] = rescaled(c->p[k], shift[i] + shift[j], sat);
        }
    }
    for (i = 0; i < c->n; ++i) {
        c->e[i] += shift[i];
    }
}

/** Wide variance in Q`q` as a Q30 mantissa of state i's scale: var * 2^(30 - q - 2 e_i). */
static imu_wide_t variance_mantissa(const imu_cov_t *c, int i, imu_wide_t var, int q, uint32_t *sat)
{
    return wide_ldexp(var, 30 - q - 2 * c->e[i], sat);
}

void imu_cov_init(imu_cov_t *c, int n, const imu_wide_t var[], int var_q, uint32_t *sat)
{
    imu_wide_t d[IMU_COV_MAX];
    int i;
    c->n = n;
    for (i = 0; i < IMU_COV_CELLS; ++i) {
        c->p[i] = 0;
    }
    for (i = 0; i < IMU_COV_MAX; ++i) {
        c->e[i] = 0;
    }
    for (i = 0; i < n; ++i) {
        c->e[i] = exponent_for(var[i], var_q);
        d[i] = variance_mantissa(c, i, var[i], var_q, sat);
    }
    store_diagonal(c, d, sat);
}

void imu_cov_reset_state(imu_cov_t *c, int i, imu_wide_t var, int var_q, uint32_t *sat)
{
    imu_wide_t d[IMU_COV_MAX];
    int j;
    for (j = 0; j < c->n; ++j) {
        c->p[cell(i, j)] = 0;
        d[j] = c->p[cell(j, j)];
    }
    c->e[i] = exponent_for(var, var_q);
    d[i] = variance_mantissa(c, i, var, var_q, sat);
    store_diagonal(c, d, sat);
}

/** The columns where `row` (of phi) is non-zero (ascending); their count returned. */
static int row_support(const imu_cov_t *c, const imu_q30_t row[IMU_COV_MAX], unsigned char cols[IMU_COV_MAX])
{
    int k, count = 0;
    for (k = 0; k < c->n; ++k) {
        if (row[k] != 0) {
            cols[count++] = (unsigned char)k;
        }
    }
    return count;
}

/** phi~ P~ phi~^T in parts (imu_cov_predict): the moving rows of phi~ as int32 multipliers,
 *  and their rows of m = phi~ P~ as int32 rows with an exponent each (every other row of m
 *  is P~'s own). */
typedef struct {
    imu_real_t m[IMU_COV_MOVING_MAX][IMU_COV_MAX]; /* m_ij (P~ units) = m[s][j] 2^m_exp[s], s = slot[i] */
    int m_exp[IMU_COV_MOVING_MAX];
    const imu_q30_t (*a)[IMU_COV_MAX]; /* phi~_{i,cols[s][t]} = a[s][t] 2^-f[s]: the rows themselves (scaled_row) */
    int f[IMU_COV_MOVING_MAX];
    unsigned char cols[IMU_COV_MOVING_MAX][IMU_COV_MAX]; /* the columns where the row is not zero */
    int count[IMU_COV_MOVING_MAX];
    signed char slot[IMU_COV_MAX]; /* state i's row among the moving ones; -1: the identity's */
} transition_t;

/** (phi~ P~ phi~^T)_ij, Q30 in the old exponents (wide). P~ is read only at (i, j) itself
 *  (both rows the identity's), so the prediction may store each element as it goes. */
static inline imu_wide_t transformed(const imu_cov_t *c, const transition_t *tr, int i, int j, uint32_t *sat)
{
    const int si = tr->slot[i], sj = tr->slot[j];
    imu_wide_t sum = 0; /* below 2^62 (scaled_row) */
    int t;
    if (si < 0 && sj < 0) {
        return c->p[cell(i, j)];
    }
    if (sj < 0) {
        return real_ldexp(tr->m[si][j], tr->m_exp[si], sat);
    }
    if (si < 0) {
        return real_ldexp(tr->m[sj][i], tr->m_exp[sj], sat); /* (P~ phi~^T)_ij = (phi~ P~)_ji: P~ is symmetric */
    }
    for (t = 0; t < tr->count[sj]; ++t) {
        sum += IMU_WMUL(tr->m[si][tr->cols[sj][t]], tr->a[sj][t]);
    }
    return wide_ldexp(sum, tr->m_exp[si] - tr->f[sj], sat);
}

/** Index in a block's upper triangle (imu_cov_predict) of its element (i, j), i, j < 3. */
static const unsigned char BLOCK_CELL[3][3] = {{0, 1, 2}, {1, 3, 4}, {2, 4, 5}};

void imu_cov_predict(imu_cov_t *c, imu_q30_t rows[][IMU_COV_MAX], const int moving[], int count,
                     const imu_wide_t qvar[], const imu_wide_t block[IMU_COV_BLOCK_CELLS], int qvar_q,
                     uint32_t *sat)
{
    /* Scaled coordinates: phi~_ik = phi_ik 2^(e_k - e_i); P~' = phi~ P~ phi~^T. Each moving
     * row of phi~ is a row of int32 multipliers with an exponent of its own (scaled_row), so
     * both products accumulate without a shift per term; each of their rows of m = phi~ P~
     * is brought below 2^31 with an exponent of its own. Only the non-zero entries of phi
     * take part, and a row of the identity (most of a filter's transition) leaves P~'s row
     * as it is: no int64 product or sum overflows, and only a truly out-of-range result
     * saturates. The new diagonal comes first: it sets the new exponents, in which every
     * other element is then stored at once. */
    transition_t tr;
    imu_wide_t d[IMU_COV_MAX];
    signed char shift[IMU_COV_MAX]; /* exponent changes, |shift| <= 17 */
    const int n = c->n;
    int i, j, k, s, t;
    tr.a = (const imu_q30_t(*)[IMU_COV_MAX])rows;
    for (i = 0; i < n; ++i) {
        tr.slot[i] = -1;
    }
    for (s = 0; s < count; ++s) {
        const int r = moving[s];
        tr.count[s] = row_support(c, rows[s], tr.cols[s]);
        if (tr.count[s] == 1 && tr.cols[s][0] == r && rows[s][r] == IMU_ONE_Q30) {
            continue; /* a row of the identity after all */
        }
        tr.slot[r] = (signed char)s;
        tr.f[s] = scaled_row(c, rows[s], r, tr.count[s], tr.cols[s], sat);
        {
            imu_wide_t *row = d; /* the row of m, value row[j] 2^-f[s] (below 2^61); d is free until later */
            imu_wide_t biggest = 0;
            int row_shift;
            for (j = 0; j < n; ++j) {
                const unsigned char *cells = CELL_INDEX[j]; /* P~_kj at cells[k] (P~ is symmetric) */
                imu_wide_t sum = 0;
                for (t = 0; t < tr.count[s]; ++t) {
                    sum += IMU_WMUL(tr.a[s][t], c->p[cells[tr.cols[s][t]]]);
                }
                row[j] = sum;
                biggest = wide_abs(sum) > biggest ? wide_abs(sum) : biggest;
            }
            row_shift = headroom(biggest, 31);
            for (j = 0; j < n; ++j) {
                tr.m[s][j] = shifted_int32(row[j], row_shift, sat);
            }
            tr.m_exp[s] = row_shift - tr.f[s];
        }
    }
    for (i = 0; i < n; ++i) {
        d[i] = transformed(c, &tr, i, i, sat) + variance_mantissa(c, i, qvar[i], qvar_q, sat); /* below 2^62 each */
        if (block != NULL && i < 3) {
            d[i] += variance_mantissa(c, i, block[BLOCK_CELL[i][i]], qvar_q, sat);
        }
    }
    diagonal_shifts(c, d, shift, sat);
    for (i = 0; i < n; ++i) {
        k = cell(i, i);
        c->p[k] = rescaled(d[i], 2 * shift[i], sat);
        for (j = i + 1, ++k; j < n; ++j, ++k) {
            if (block != NULL && j < 3) {
                /* B_ij in the old exponents: at most the geometric mean of B_ii and B_jj in
                 * theirs, and the sum at most that of two diagonals of d */
                const imu_wide_t b = wide_ldexp(block[BLOCK_CELL[i][j]], 30 - qvar_q - c->e[i] - c->e[j], sat);
                c->p[k] = rescaled(transformed(c, &tr, i, j, sat) + b, shift[i] + shift[j], sat);
            } else if (!(tr.slot[i] < 0 && tr.slot[j] < 0 && shift[i] + shift[j] == 0)) { /* else P~_ij stays */
                c->p[k] = rescaled(transformed(c, &tr, i, j, sat), shift[i] + shift[j], sat);
            }
        }
    }
    for (i = 0; i < n; ++i) {
        c->e[i] += shift[i];
    }
}

/**
 * The part of P h that a gain map leaves out, in scaled coordinates: with u_i = ch_i 2^(e_i + E),
 * o = u - G u gives oh_i = ch_i - sum_j G_ij 2^(e_j - e_i) ch_j, G_ij the block's: 0, 1 on
 * the diagonal (oh_i = 0), or v_i v_j.
 */
static void left_out(const imu_cov_t *c, const imu_real_t ch[], const imu_cov_map_t *gain_map, imu_wide_t oh[],
                     uint32_t *sat)
{
    const imu_q30_t *v = gain_map->along;
    imu_q30_t g[3][3]; /* v v^T, Q30: each product once, when a block is corrected along v */
    int along = 0;
    int i, j;
    for (i = 0; 3 * i < c->n; ++i) { /* the blocks (the last may be partial) */
        along |= gain_map->block[i] == IMU_COV_BLOCK_ALONG;
    }
    for (i = 0; along && i < 3; ++i) {
        for (j = i; j < 3; ++j) {
            g[i][j] = g[j][i] = IMU_MUL(v[i], v[j], 30);
        }
    }
    for (i = 0; i < c->n; ++i) {
        const int first = i - i % 3;
        oh[i] = 0;
        if (gain_map->block[i / 3] == IMU_COV_BLOCK_ALL) {
            continue; /* nothing left out (ch_i - ch_i) */
        }
        oh[i] = ch[i];
        if (gain_map->block[i / 3] != IMU_COV_BLOCK_ALONG) {
            continue; /* all left out */
        }
        for (j = first; j < first + 3 && j < c->n; ++j) {
            /* |ch_j| <= 2^30, |G_ij| <= 2^30: the product is below 2^30 again */
            if (g[i - first][j - first] != 0) {
                oh[i] -= real_ldexp(IMU_MUL(ch[j], g[i - first][j - first], 30), c->e[j] - c->e[i], sat);
            }
        }
    }
}

int imu_cov_update(imu_cov_t *c, const imu_q30_t h[], imu_wide_t r, int r_q, imu_q30_t z, imu_q30_t w,
                   const imu_cov_map_t *gain_map, imu_q30_t dx[], uint32_t *sat)
{
    /* Scaled coordinates: h~_j = h_j 2^e_j = hs_j 2^E. Then c~ = P~ h~ = 2^E (P~ hs),
     * s = h~ P~ h~ + r = 2^2E (hs P~ hs + r 2^-2E), and P~' = P~ - w c~ c~^T / s
     * = P~ - w ch ch^T / sh with ch = P~ hs, sh = w hs ch + r 2^-2E: E cancels.
     * With a gain map G (K' = G K), Joseph's form for that gain, (I - K'h) P (I - K'h)^T
     * + K' r K'^T, is P - (u u^T - o o^T) / s with u = P h^T and o = u - G u. */
    imu_q30_t hs[IMU_COV_MAX];  /* the scaled row's non-zero entries, those of the states `used` (scale_row) */
    imu_real_t ch[IMU_COV_MAX]; /* P~ hs, Q30; |ch| <= 2^30 */
    imu_wide_t oh[IMU_COV_MAX]; /* the part of ch the gain map leaves out, Q30 (written only under a map) */
    imu_wide_t cmax = 0;        /* max |ch_i| (apply_update) */
    imu_wide_t q = 0;           /* hs P~ hs, Q30 */
    imu_wide_t sh;              /* Q30 */
    unsigned char used[IMU_COV_MAX]; /* the states hs is not zero at */
    const int n = c->n;
    int big, i, t, count;
    if (w <= 0) {
        return 0;
    }
    big = scale_row(c, h, hs, used, &count, sat);
    for (i = 0; i < n; ++i) {
        const unsigned char *row = CELL_INDEX[i]; /* (the storage index of (i, j) is row[j]) */
        imu_wide_t sum = 0;                       /* Q60, below 2^60 (scale_row) */
        for (t = 0; t < count; ++t) {
            sum += IMU_WMUL(c->p[row[used[t]]], hs[t]);
        }
        ch[i] = (imu_real_t)Q60_TO_Q30(sum);
        cmax = wide_abs(ch[i]) > cmax ? wide_abs(ch[i]) : cmax;
    }
    for (t = 0; t < count; ++t) {
        q += IMU_WMUL(ch[used[t]], hs[t]); /* Q60, below 2^60 */
    }
    q = Q60_TO_Q30(q);
    if (noise_dwarfs_row(r, 30 - r_q - 2 * big)) {
        return 0; /* no information (not a saturation: the gain would round to zero) */
    }
    /* sh = w q + r 2^-2E (Q30); q is at most 2^30. */
    sh = wide_mul_q30(q, w) + wide_ldexp(r, 30 - r_q - 2 * big, sat);
    if (sh <= 0) {
        ++*sat;
        return 0;
    }
    if (gain_map != 0) {
        left_out(c, ch, gain_map, oh, sat);
    }
    apply_update(c, ch, cmax, oh, gain_map, sh, w, z, big, dx, sat);
    return 1;
}

void imu_cov_cap_unit_variance(imu_cov_t *c, int i)
{
    cap_unit_variance(c, i);
}

void imu_cov_scale_up(imu_cov_t *c, const int k[])
{
    int i;
#ifdef IMU_FIXED
    for (i = 0; i < c->n; ++i) {
        c->e[i] += k[i]; /* P_ij 2^(e_i + e_j): 2^(k_i + k_j) */
    }
#else
    double scale[IMU_COV_MAX]; /* 2^k_i */
    int j;
    for (i = 0; i < c->n; ++i) {
        scale[i] = 1.0;
        for (j = 0; j < k[i]; ++j) {
            scale[i] *= 2.0;
        }
    }
    for (i = 0; i < c->n; ++i) {
        for (j = i; j < c->n; ++j) {
            c->p[cell(i, j)] *= scale[i] * scale[j];
        }
    }
#endif
}

imu_wide_t imu_cov_element_wide(const imu_cov_t *c, int i, int j, int q, uint32_t *sat)
{
    return real_ldexp(c->p[cell(i, j)], c->e[i] + c->e[j] + q - 30, sat); /* (the identity in the float build) */
}

imu_real_t imu_cov_element_q30(const imu_cov_t *c, int i, int j, uint32_t *sat)
{
    return IMU_WIDE_SAT(imu_cov_element_wide(c, i, j, 30, sat), sat);
}

void imu_cov_get(const imu_cov_t *c, int i, int j, imu_real_t *mant, int32_t *exp)
{
    *mant = c->p[cell(i, j)];
    *exp = c->e[i] + c->e[j];
}
