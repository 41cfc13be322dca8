/**
 * @file imu_cov.c
 * @brief Block-floating symmetric covariance (see imu_cov.h).
 *
 * The algorithms below are shared by both builds; only the handful of helpers in
 * the first section differ: in the float build, exponents stay 0, scaling by 2^n
 * is exact and formats are annotations.
 */
#include "imu_cov.h"

/** Index of (i, j), i <= j, in the upper-triangle storage. */
static int cell(int i, int j)
{
    if (i > j) {
        const int t = i;
        i = j;
        j = t;
    }
    return i * IMU_COV_MAX - i * (i - 1) / 2 + (j - i);
}

static void load_wide(const imu_cov_t *c, imu_wide_t w[IMU_COV_CELLS])
{
    int k;
    for (k = 0; k < IMU_COV_CELLS; ++k) {
        w[k] = c->p[k];
    }
}

#ifdef IMU_FIXED

#define WIDE_LIMIT ((int64_t)1 << 62)

/** v * 2^n: rounded for n < 0, saturated to +-2^62 for n > 0. */
static inline imu_wide_t wide_ldexp(imu_wide_t v, int n, uint32_t *sat)
{
    if (n < 0) {
        return n < -62 ? 0 : imu_rshift_round64(v, -n);
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

/** A value brought below 2^31 by headroom(., 31) and a rounding shift, as int32: the
 *  rounding can reach +2^31 exactly, which becomes INT32_MAX (one unit in 2^31). */
static imu_real_t headroom_int32(imu_wide_t v)
{
    return (imu_real_t)(v > INT32_MAX ? INT32_MAX : v);
}

/**
 * Choose new exponents so that every diagonal mantissa lies in [2^28, 2^30), and
 * store the rescaled wide matrix `w` (Q30 in the old exponents) as int32.
 */
static void renormalize(imu_cov_t *c, imu_wide_t w[IMU_COV_CELLS], uint32_t *sat)
{
    int shift[IMU_COV_MAX];
    int i, j;
    for (i = 0; i < c->n; ++i) {
        imu_wide_t *d = &w[cell(i, i)];
        if (*d <= 0) {
            ++*sat; /* rounding destroyed this variance: restart it at the smallest normalised value */
            *d = (int64_t)1 << 28;
        }
        /* s = ceil((bits - 30) / 2): d * 2^(-2s) in [2^28, 2^30). */
        {
            const int excess = imu_bit_length64((uint64_t)*d) - 30;
            shift[i] = excess >= 0 ? (excess + 1) / 2 : -((-excess) / 2);
        }
    }
    for (i = 0; i < c->n; ++i) {
        for (j = i; j < c->n; ++j) {
            const int k = cell(i, j);
            const int down = shift[i] + shift[j]; /* mostly 0: the exponents rarely move */
            c->p[k] = imu_sat32(down == 0 ? w[k] : wide_ldexp(w[k], -down, sat), sat);
        }
        c->e[i] += shift[i];
    }
}

/** Q30 measurement row scaled by 2^(e_j - E), with E chosen so the largest entry is in [2^29, 2^30]. */
static int scale_row(const imu_cov_t *c, const imu_q30_t h[], imu_q30_t hs[], uint32_t *sat)
{
    int big = INT32_MIN;
    int j;
    for (j = 0; j < c->n; ++j) {
        if (h[j] != 0) {
            const int mag = c->e[j] + imu_bit_length64((uint64_t)(h[j] < 0 ? -(int64_t)h[j] : h[j])) - 30;
            big = mag > big ? mag : big;
        }
    }
    if (big == INT32_MIN) {
        big = 0;
    }
    for (j = 0; j < c->n; ++j) {
        hs[j] = (imu_q30_t)wide_ldexp(h[j], c->e[j] - big, sat);
    }
    return big;
}

/** v = mant * 2^exp with |mant| in [2^29, 2^30) (mant = 0 for v = 0). */
static int32_t normalize_wide(imu_wide_t v, int *exp)
{
    const int bits = imu_bit_length64((uint64_t)(v < 0 ? -v : v));
    *exp = bits - 30;
    return (int32_t)(bits > 30 ? imu_rshift_round64(v, bits - 30) : v * ((int64_t)1 << (30 - bits)));
}

/**
 * P~ -= (w / sh) ch ch^T and dx_i = (w z / sh) ch_i 2^(e_i - E) (Q30), with every
 * int64 product below 2^62: ch is normalised to 30-bit mantissas, the two
 * scalars w/sh and w z/sh to mantissa and exponent.
 */
static void apply_update(imu_cov_t *c, const imu_wide_t ch[], const imu_wide_t oh[], imu_wide_t sh, imu_q30_t w,
                         imu_q30_t z, int big, imu_q30_t dx[], uint32_t *sat)
{
    int32_t cm[IMU_COV_MAX], om[IMU_COV_MAX];
    imu_wide_t wm[IMU_COV_CELLS];
    imu_wide_t cmax = 0;
    int ce, ke, ve, i, j;
    int32_t k_mant, v_mant;
    for (i = 0; i < c->n; ++i) {
        const imu_wide_t a = wide_abs(ch[i]), b = wide_abs(oh[i]);
        cmax = a > cmax ? a : cmax;
        cmax = b > cmax ? b : cmax;
    }
    if (cmax == 0) {
        return;
    }
    normalize_wide(cmax, &ce); /* ch_i = cm_i 2^ce, |cm_i| < 2^30; the same for oh */
    for (i = 0; i < c->n; ++i) {
        cm[i] = (int32_t)wide_ldexp(ch[i], -ce, sat);
        om[i] = (int32_t)wide_ldexp(oh[i], -ce, sat);
    }
    /* w / sh: Q30 / Q30 as (w 2^32) / sh = k 2^(-32); normalised. */
    k_mant = normalize_wide(((imu_wide_t)w * ((int64_t)1 << 32)) / sh, &ke);
    ke -= 32;
    /* w z / sh: (w z (Q60)) >> 30 -> Q30, then the same division. */
    v_mant = normalize_wide((imu_rshift_round64((imu_wide_t)w * z, 30) * ((int64_t)1 << 31)) / sh, &ve);
    ve -= 31;
    load_wide(c, wm);
    for (i = 0; i < c->n; ++i) {
        /* dx_i = v (cm_i - om_i) 2^(ve + ce + e_i - E) in Q30: v_mant * (cm_i - om_i) < 2^61. */
        dx[i] = imu_sat32(wide_ldexp((imu_wide_t)v_mant * (cm[i] - om[i]), ve + ce + c->e[i] - big, sat), sat);
        for (j = i; j < c->n; ++j) {
            /* ((cm_i cm_j - om_i om_j) >> 30) * k_mant < 2^61; value 2^(2 ce + ke + 30) in Q30 units. */
            const imu_wide_t cc = imu_rshift_round64((imu_wide_t)cm[i] * cm[j] - (imu_wide_t)om[i] * om[j], 30);
            wm[cell(i, j)] -= wide_ldexp(cc * k_mant, 2 * ce + ke, sat);
        }
    }
    renormalize(c, wm, sat);
}

/** Wide Q58 value back to Q30. */
#define Q58_TO_Q30(v) imu_rshift_round64((v), 28)

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

static imu_real_t headroom_int32(imu_wide_t v)
{
    return v;
}

static void renormalize(imu_cov_t *c, imu_wide_t w[IMU_COV_CELLS], uint32_t *sat)
{
    int i, j;
    for (i = 0; i < c->n; ++i) {
        if (w[cell(i, i)] <= 0.0) {
            ++*sat;
            w[cell(i, i)] = 1e-30;
        }
        for (j = i; j < c->n; ++j) {
            c->p[cell(i, j)] = w[cell(i, j)];
        }
    }
}

static int scale_row(const imu_cov_t *c, const imu_q30_t h[], imu_q30_t hs[], uint32_t *sat)
{
    int j;
    (void)sat;
    for (j = 0; j < c->n; ++j) {
        hs[j] = h[j];
    }
    return 0;
}

static void apply_update(imu_cov_t *c, const imu_wide_t ch[], const imu_wide_t oh[], imu_wide_t sh, imu_q30_t w,
                         imu_q30_t z, int big, imu_q30_t dx[], uint32_t *sat)
{
    imu_wide_t wm[IMU_COV_CELLS];
    int i, j;
    (void)big;
    load_wide(c, wm);
    for (i = 0; i < c->n; ++i) {
        dx[i] = w * z / sh * (ch[i] - oh[i]);
        for (j = i; j < c->n; ++j) {
            wm[cell(i, j)] -= w / sh * (ch[i] * ch[j] - oh[i] * oh[j]);
        }
    }
    renormalize(c, wm, sat);
}

#define Q58_TO_Q30(v) (v)

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

/** Wide variance in Q`q` as a Q30 mantissa of state i's scale: var * 2^(30 - q - 2 e_i). */
static imu_wide_t variance_mantissa(const imu_cov_t *c, int i, imu_wide_t var, int q, uint32_t *sat)
{
    return wide_ldexp(var, 30 - q - 2 * c->e[i], sat);
}

void imu_cov_init(imu_cov_t *c, int n, const imu_wide_t var[], int var_q, uint32_t *sat)
{
    imu_wide_t w[IMU_COV_CELLS];
    int i;
    c->n = n;
    for (i = 0; i < IMU_COV_CELLS; ++i) {
        w[i] = 0;
    }
    for (i = 0; i < IMU_COV_MAX; ++i) {
        c->e[i] = 0;
    }
    for (i = 0; i < n; ++i) {
        c->e[i] = exponent_for(var[i], var_q);
        w[cell(i, i)] = variance_mantissa(c, i, var[i], var_q, sat);
    }
    renormalize(c, w, sat);
}

void imu_cov_reset_state(imu_cov_t *c, int i, imu_wide_t var, int var_q, uint32_t *sat)
{
    imu_wide_t w[IMU_COV_CELLS];
    int j;
    load_wide(c, w);
    for (j = 0; j < c->n; ++j) {
        w[cell(i, j)] = 0;
    }
    c->e[i] = exponent_for(var, var_q);
    w[cell(i, i)] = variance_mantissa(c, i, var, var_q, sat);
    renormalize(c, w, sat);
}

/** The columns where row i of phi is non-zero (ascending; their count returned), and
 *  the largest e_k - e_i over them (how far a term can grow). */
static int row_support(const imu_cov_t *c, imu_q30_t phi[][IMU_COV_MAX], int i, unsigned char cols[IMU_COV_MAX],
                       int *growth)
{
    int k, count = 0;
    *growth = 0;
    for (k = 0; k < c->n; ++k) {
        if (phi[i][k] != 0) {
            cols[count++] = (unsigned char)k;
            if (c->e[k] - c->e[i] > *growth) {
                *growth = c->e[k] - c->e[i];
            }
        }
    }
    return count;
}

void imu_cov_predict(imu_cov_t *c, imu_q30_t phi[][IMU_COV_MAX], const imu_wide_t qvar[], int qvar_q,
                     uint32_t *sat)
{
    /* Scaled coordinates: phi~_ik = phi_ik 2^(e_k - e_i); P~' = phi~ P~ phi~^T.
     * Mixed states may have very different exponents (a large heading variance
     * rotated into a small tilt one), so both products accumulate in a format
     * lowered by the row's largest exponent difference (every term is then shifted
     * right only), and each row of m = phi~ P~ is brought below 2^31 by row_shift,
     * with the row's total scale kept in row_scale: no int64 product or sum
     * overflows, and only a truly out-of-range result saturates. Only the non-zero
     * entries of phi take part (a filter's transition is mostly identity). */
    imu_real_t m[IMU_COV_MAX][IMU_COV_MAX]; /* m_ij (Q30) = m[i][j] * 2^row_scale[i], |m[i][j]| < 2^31 */
    imu_wide_t row[IMU_COV_MAX];            /* a row of m before its shift */
    int row_scale[IMU_COV_MAX];
    unsigned char cols[IMU_COV_MAX][IMU_COV_MAX];
    int count[IMU_COV_MAX], growth[IMU_COV_MAX];
    imu_wide_t w[IMU_COV_CELLS];
    const int n = c->n;
    int i, j, k, t;
    for (i = 0; i < n; ++i) {
        count[i] = row_support(c, phi, i, cols[i], &growth[i]);
    }
    for (i = 0; i < n; ++i) {
        imu_wide_t biggest = 0;
        int row_shift;
        for (j = 0; j < n; ++j) {
            imu_wide_t sum = 0;
            for (t = 0; t < count[i]; ++t) {
                k = cols[i][t];
                /* Q30 * Q30 -> Q60 (below 2^61), to Q56 - growth: 9 terms below 2^61. */
                sum += wide_ldexp(IMU_WMUL(phi[i][k], c->p[cell(k, j)]), c->e[k] - c->e[i] - growth[i] - 4, sat);
            }
            row[j] = sum;
            biggest = wide_abs(sum) > biggest ? wide_abs(sum) : biggest;
        }
        row_shift = headroom(biggest, 31);
        for (j = 0; j < n; ++j) {
            m[i][j] = headroom_int32(wide_ldexp(row[j], -row_shift, sat));
        }
        row_scale[i] = growth[i] - 26 + row_shift; /* Q56 -> Q30 is 2^-26 */
    }
    for (i = 0; i < n; ++i) {
        for (j = i; j < n; ++j) {
            imu_wide_t sum = 0;
            for (t = 0; t < count[j]; ++t) {
                k = cols[j][t];
                /* (|m| < 2^31) * Q30 -> below 2^62, to Q-4 - growth: 9 terms below 2^62. */
                sum += wide_ldexp(IMU_WMUL(m[i][k], phi[j][k]), c->e[k] - c->e[j] - growth[j] - 4, sat);
            }
            /* sum * 2^(growth + 4 - 30) is in units of m; times 2^row_scale -> Q30. */
            w[cell(i, j)] = wide_ldexp(sum, growth[j] - 26 + row_scale[i], sat);
        }
        w[cell(i, i)] += variance_mantissa(c, i, qvar[i], qvar_q, sat); /* both below 2^62 */
    }
    renormalize(c, w, sat);
}

/**
 * The part of P h that a gain map leaves out, in scaled coordinates: with u_i = ch_i 2^(e_i + E),
 * o = u - G u gives oh_i = ch_i - sum_j G_ij 2^(e_j - e_i) ch_j (zero without a map).
 */
static void left_out(const imu_cov_t *c, const imu_wide_t ch[], const imu_q30_t (*gain_map)[IMU_COV_MAX],
                     imu_wide_t oh[], uint32_t *sat)
{
    int i, j;
    for (i = 0; i < c->n; ++i) {
        oh[i] = 0;
        if (gain_map != 0) {
            oh[i] = ch[i];
            for (j = 0; j < c->n; ++j) {
                if (gain_map[i][j] != 0) {
                    oh[i] -= wide_ldexp(wide_mul_q30(ch[j], gain_map[i][j]), c->e[j] - c->e[i], sat);
                }
            }
        }
    }
}

int imu_cov_update(imu_cov_t *c, const imu_q30_t h[], imu_wide_t r, int r_q, imu_q30_t z, imu_q30_t w,
                   const imu_q30_t (*gain_map)[IMU_COV_MAX], imu_q30_t dx[], uint32_t *sat)
{
    /* Scaled coordinates: h~_j = h_j 2^e_j = hs_j 2^E. Then c~ = P~ h~ = 2^E (P~ hs),
     * s = h~ P~ h~ + r = 2^2E (hs P~ hs + r 2^-2E), and P~' = P~ - w c~ c~^T / s
     * = P~ - w ch ch^T / sh with ch = P~ hs, sh = w hs ch + r 2^-2E: E cancels.
     * With a gain map G (K' = G K), Joseph's form for that gain, (I - K'h) P (I - K'h)^T
     * + K' r K'^T, is P - (u u^T - o o^T) / s with u = P h^T and o = u - G u. */
    imu_q30_t hs[IMU_COV_MAX];
    imu_wide_t ch[IMU_COV_MAX]; /* P~ hs, Q30; |ch| < 9 * 2^30 */
    imu_wide_t oh[IMU_COV_MAX]; /* the part of ch the gain map leaves out, Q30 */
    imu_wide_t q = 0;           /* hs P~ hs, Q30 */
    imu_wide_t sh;              /* Q30 */
    const int n = c->n;
    int big, i, j;
    if (w <= 0) {
        return 0;
    }
    big = scale_row(c, h, hs, sat);
    for (i = 0; i < n; ++i) {
        imu_wide_t sum = 0;
        for (j = 0; j < n; ++j) {
            if (hs[j] != 0) {
                /* Q30 * Q30 -> Q60 -> Q58: 9 terms below 2^58 each. */
                sum += wide_ldexp(IMU_WMUL(c->p[cell(i, j)], hs[j]), -2, sat);
            }
        }
        ch[i] = Q58_TO_Q30(sum);
    }
    for (i = 0; i < n; ++i) {
        /* Q28 * Q30 -> Q58 (below 2^62) -> Q30. */
        q += wide_ldexp(wide_ldexp(ch[i], -2, sat) * hs[i], -28, sat);
    }
    if (noise_dwarfs_row(r, 30 - r_q - 2 * big)) {
        return 0; /* no information (not a saturation: the gain would round to zero) */
    }
    /* sh = w q + r 2^-2E (Q30); q is below 81 * 2^30. */
    sh = wide_mul_q30(q, w) + wide_ldexp(r, 30 - r_q - 2 * big, sat);
    if (sh <= 0) {
        ++*sat;
        return 0;
    }
    left_out(c, ch, gain_map, oh, sat);
    apply_update(c, ch, oh, sh, w, z, big, dx, sat);
    return 1;
}

void imu_cov_cap_unit_variance(imu_cov_t *c, int i)
{
    cap_unit_variance(c, i);
}

imu_real_t imu_cov_element_q30(const imu_cov_t *c, int i, int j, uint32_t *sat)
{
    return IMU_WIDE_SAT(wide_ldexp(c->p[cell(i, j)], c->e[i] + c->e[j], sat), sat);
}

void imu_cov_get(const imu_cov_t *c, int i, int j, imu_real_t *mant, int32_t *exp)
{
    *mant = c->p[cell(i, j)];
    *exp = c->e[i] + c->e[j];
}
