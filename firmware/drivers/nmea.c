/**
 * @file nmea.c
 * @brief NMEA 0183 GGA, RMC, VTG (see nmea.h).
 */
#include "nmea.h"

/** Where the next byte goes. */
enum { WAIT_DOLLAR, IN_SENTENCE, CHECKSUM_1, CHECKSUM_2 };

void nmea_parser_init(nmea_parser_t *p)
{
    p->length = 0;
    p->text[0] = '\0';
    p->state = WAIT_DOLLAR;
    p->checksum = p->given = 0;
    p->sentences = p->checksum_errors = p->too_long = 0;
}

static int hex_digit(uint8_t c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
}

int nmea_parser_push(nmea_parser_t *p, uint8_t byte)
{
    int digit;
    if (byte == '$') { /* a new sentence, whatever came before */
        if (p->state != WAIT_DOLLAR) {
            ++p->checksum_errors; /* one that ended without its checksum */
        }
        p->state = IN_SENTENCE;
        p->length = 0;
        p->checksum = 0;
        return 0;
    }
    switch (p->state) {
    case IN_SENTENCE:
        if (byte == '*') {
            p->text[p->length] = '\0';
            p->state = CHECKSUM_1;
        } else if (byte == '\r' || byte == '\n') {
            ++p->checksum_errors;
            p->state = WAIT_DOLLAR;
        } else if (p->length + 5u >= NMEA_MAX_SENTENCE) { /* "$", "*", two digits, CR LF: no room */
            ++p->too_long;
            p->state = WAIT_DOLLAR;
        } else {
            p->text[p->length++] = (char)byte;
            p->checksum ^= byte;
        }
        return 0;
    case CHECKSUM_1:
        digit = hex_digit(byte);
        if (digit < 0) {
            ++p->checksum_errors;
            p->state = WAIT_DOLLAR;
        } else {
            p->given = (uint8_t)(digit << 4);
            p->state = CHECKSUM_2;
        }
        return 0;
    case CHECKSUM_2:
        digit = hex_digit(byte);
        p->state = WAIT_DOLLAR;
        if (digit < 0 || (uint8_t)(p->given | digit) != p->checksum) {
            ++p->checksum_errors;
            return 0;
        }
        ++p->sentences;
        return 1;
    default: /* WAIT_DOLLAR: UBX frames, noise, the CR LF after a sentence */
        return 0;
    }
}

/** Field `k` of the sentence (0: talker and type): its start and length; 0 when there is none. */
static int field(const nmea_parser_t *p, int k, const char **start, int *length)
{
    const char *s = p->text;
    while (k > 0) {
        while (*s != ',' && *s != '\0') {
            ++s;
        }
        if (*s == '\0') {
            return 0;
        }
        ++s;
        --k;
    }
    *start = s;
    *length = 0;
    while (s[*length] != ',' && s[*length] != '\0') {
        ++*length;
    }
    return 1;
}

/** "123.45" as an integer with `decimals` decimals (more are cut, fewer padded): 0 for an
 *  empty field, any other character, or a value beyond 32 bits. */
static int decimal(const char *s, int length, int decimals, uint32_t *out)
{
    uint64_t value = 0; /* below 2^32 * 10 + 9 at every step: checked after each digit */
    int i, point = -1, fraction = 0, digits = 0;
    if (length <= 0) {
        return 0;
    }
    for (i = 0; i < length; ++i) {
        if (s[i] == '.' && point < 0) {
            point = i;
        } else if (s[i] >= '0' && s[i] <= '9') {
            if (point >= 0 && fraction == decimals) {
                continue; /* beyond the resolution kept */
            }
            value = value * 10u + (uint64_t)(s[i] - '0');
            fraction += point >= 0;
            ++digits;
        } else {
            return 0;
        }
        if (value > 0xFFFFFFFFu) {
            return 0;
        }
    }
    if (digits == 0) {
        return 0; /* "." alone */
    }
    for (; fraction < decimals; ++fraction) {
        value *= 10u;
        if (value > 0xFFFFFFFFu) {
            return 0;
        }
    }
    *out = (uint32_t)value;
    return 1;
}

static int field_decimal(const nmea_parser_t *p, int k, int decimals, uint32_t *out)
{
    const char *s;
    int length;
    return field(p, k, &s, &length) && decimal(s, length, decimals, out);
}

/** A signed field ("-12.5"), `decimals` decimals. */
static int field_signed(const nmea_parser_t *p, int k, int decimals, int32_t *out)
{
    const char *s;
    int length, negative;
    uint32_t magnitude;
    if (!field(p, k, &s, &length) || length == 0) {
        return 0;
    }
    negative = s[0] == '-';
    if (!decimal(s + negative, length - negative, decimals, &magnitude) || magnitude > 0x7FFFFFFFu) {
        return 0;
    }
    *out = negative ? -(int32_t)magnitude : (int32_t)magnitude;
    return 1;
}

/** hhmmss.sss as ms of the day. */
static int field_time(const nmea_parser_t *p, int k, uint32_t *ms)
{
    uint32_t v, h, m, s_ms;
    if (!field_decimal(p, k, 3, &v)) {
        return 0;
    }
    h = v / 10000000u;
    m = v / 100000u % 100u;
    s_ms = v % 100000u;
    if (h > 23u || m > 59u || s_ms > 60999u) {
        return 0;
    }
    *ms = (h * 3600u + m * 60u) * 1000u + s_ms;
    return 1;
}

/** (d)ddmm.mmmmm and its hemisphere (field k + 1) as 1e-7 deg: the minutes exactly, rounded. */
static int field_angle(const nmea_parser_t *p, int k, char positive, char negative, uint32_t max_deg, int32_t *out)
{
    const char *h;
    int length;
    uint32_t v, deg, minutes_1e5, value;
    if (!field_decimal(p, k, 5, &v) || !field(p, k + 1, &h, &length) || length != 1 ||
        (h[0] != positive && h[0] != negative)) {
        return 0;
    }
    deg = v / 10000000u; /* v < 2^32: 18000.00000 -> 1.8e9 */
    minutes_1e5 = v % 10000000u;
    if (deg > max_deg || minutes_1e5 >= 6000000u) {
        return 0;
    }
    value = deg * 10000000u + (minutes_1e5 * 100u + 30u) / 60u; /* minutes 1e-5 -> deg 1e-7 */
    if (value > max_deg * 10000000u) {
        return 0;
    }
    *out = h[0] == negative ? -(int32_t)value : (int32_t)value;
    return 1;
}

int nmea_is(const nmea_parser_t *p, const char *type)
{
    const char *s;
    int length, i;
    if (!field(p, 0, &s, &length) || length != 5) {
        return 0;
    }
    for (i = 0; i < 3; ++i) {
        if (s[2 + i] != type[i]) {
            return 0;
        }
    }
    return type[3] == '\0';
}

int nmea_gga(const nmea_parser_t *p, nmea_gga_t *out)
{
    uint32_t quality, num_sv, hdop;
    nmea_gga_t g;
    if (!nmea_is(p, "GGA") || !field_time(p, 1, &g.time_ms) || !field_angle(p, 2, 'N', 'S', 90u, &g.lat_1e7deg) ||
        !field_angle(p, 4, 'E', 'W', 180u, &g.lon_1e7deg) || !field_decimal(p, 6, 0, &quality) || quality > 9u ||
        !field_decimal(p, 7, 0, &num_sv) || num_sv > 255u || !field_decimal(p, 8, 2, &hdop) || hdop > 65535u ||
        !field_signed(p, 9, 3, &g.alt_msl_mm) || !field_signed(p, 11, 3, &g.geoid_sep_mm)) {
        return 0;
    }
    g.quality = (uint8_t)quality;
    g.num_sv = (uint8_t)num_sv;
    g.hdop_cent = (uint16_t)hdop;
    *out = g;
    return 1;
}

/** Knots with three decimals as mm/s, rounded: 1 kn = 1852 m / 3600 s. */
static uint32_t knots_to_mm_s(uint32_t knots_1000)
{
    return (uint32_t)(((uint64_t)knots_1000 * 1852u + 1800u) / 3600u);
}

int nmea_rmc(const nmea_parser_t *p, nmea_rmc_t *out)
{
    const char *status;
    int length;
    uint32_t knots;
    nmea_rmc_t r;
    if (!nmea_is(p, "RMC") || !field_time(p, 1, &r.time_ms) || !field(p, 2, &status, &length) || length != 1 ||
        (status[0] != 'A' && status[0] != 'V') || !field_angle(p, 3, 'N', 'S', 90u, &r.lat_1e7deg) ||
        !field_angle(p, 5, 'E', 'W', 180u, &r.lon_1e7deg) || !field_decimal(p, 7, 3, &knots) ||
        !field_decimal(p, 8, 5, &r.course_1e5deg) || r.course_1e5deg >= 36000000u ||
        !field_decimal(p, 9, 0, &r.date_ddmmyy)) {
        return 0;
    }
    r.active = status[0] == 'A';
    r.speed_mm_s = knots_to_mm_s(knots);
    *out = r;
    return 1;
}

int nmea_vtg(const nmea_parser_t *p, nmea_vtg_t *out)
{
    uint32_t kmh;
    nmea_vtg_t v;
    if (!nmea_is(p, "VTG") || !field_decimal(p, 1, 5, &v.course_1e5deg) || v.course_1e5deg >= 36000000u ||
        !field_decimal(p, 7, 3, &kmh)) {
        return 0;
    }
    v.speed_mm_s = (uint32_t)(((uint64_t)kmh * 10u + 18u) / 36u); /* km/h 1e-3 -> mm/s: 1000 / 3600 */
    *out = v;
    return 1;
}
