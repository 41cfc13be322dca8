/**
 * @file nmea.h
 * @brief NMEA 0183 sentences GGA, RMC and VTG: the fallback for a GNSS receiver that does
 *        not speak UBX.
 *
 * A sentence is "$", a talker (GP, GN, GL, GA, ...) and a type, comma-separated fields,
 * "*" and the two hex digits of the XOR of every character between "$" and "*", then CR LF;
 * at most 82 characters. nmea_parser_push() takes the receiver's bytes one at a time and
 * says when a whole sentence with a valid checksum is in its buffer; a sentence without a
 * checksum, with a wrong one or longer than 82 characters is counted and dropped, and UBX
 * frames between sentences are skipped. The decoders turn the fields into integers in the
 * units of ubx.h (1e-7 deg, mm, mm/s), so that both protocols feed a filter the same way:
 * ddmm.mmmmm is converted exactly to 1e-7 deg (rounded), knots to mm/s (rounded). A field
 * left empty (a receiver without a fix) makes the decoder say the value is not valid.
 *
 * No dynamic memory, integer only, no C library.
 */
#ifndef NMEA_H
#define NMEA_H

#include <stdint.h>

/** Longest sentence: "$" to LF (NMEA 0183). */
#define NMEA_MAX_SENTENCE 82u

/** A parser. All members are private but the counters. */
typedef struct {
    char text[NMEA_MAX_SENTENCE + 1]; /**< the sentence between "$" and "*", NUL-terminated */
    uint8_t length;
    uint8_t state;                    /**< where the next byte goes (nmea.c) */
    uint8_t checksum;                 /**< running XOR */
    uint8_t given;                    /**< the checksum's digits received */
    uint32_t sentences;               /**< with a valid checksum */
    uint32_t checksum_errors;         /**< a wrong or missing checksum */
    uint32_t too_long;                /**< longer than NMEA_MAX_SENTENCE */
} nmea_parser_t;

void nmea_parser_init(nmea_parser_t *p);

/** @brief Take one byte; 1 when it ended a sentence with a valid checksum (in the parser until the next call). */
int nmea_parser_push(nmea_parser_t *p, uint8_t byte);

/** GGA: the fix. */
typedef struct {
    uint32_t time_ms;      /**< UTC time of day, ms */
    int32_t lat_1e7deg;    /**< latitude, 1e-7 deg, north positive */
    int32_t lon_1e7deg;    /**< longitude, 1e-7 deg, east positive */
    uint8_t quality;       /**< 0 no fix, 1 GPS, 2 differential, 4 RTK fixed, 5 RTK float, 6 estimated */
    uint8_t num_sv;        /**< satellites used */
    uint16_t hdop_cent;    /**< horizontal DOP, 0.01 */
    int32_t alt_msl_mm;    /**< altitude above mean sea level, mm */
    int32_t geoid_sep_mm;  /**< geoid above the WGS-84 ellipsoid, mm (ellipsoid height = alt + sep) */
} nmea_gga_t;

/** RMC: the minimum: position, speed and course over ground, date. */
typedef struct {
    uint32_t time_ms;      /**< UTC time of day, ms */
    uint8_t active;        /**< status A (1) or V, void (0) */
    int32_t lat_1e7deg;
    int32_t lon_1e7deg;
    uint32_t speed_mm_s;   /**< speed over ground, mm/s */
    uint32_t course_1e5deg; /**< course over ground, true, 1e-5 deg */
    uint32_t date_ddmmyy;  /**< as sent: day, month, year */
} nmea_rmc_t;

/** VTG: course and speed over ground. */
typedef struct {
    uint32_t course_1e5deg; /**< true course, 1e-5 deg */
    uint32_t speed_mm_s;    /**< from the km/h field, mm/s */
} nmea_vtg_t;

/** @brief The sentence's type without its talker ("GGA" for $GNGGA): 1 when it is `type`. */
int nmea_is(const nmea_parser_t *p, const char *type);

/** @brief Decode the sentence in the parser; 1 when it is of that type and every field used is present and valid. */
int nmea_gga(const nmea_parser_t *p, nmea_gga_t *out);
int nmea_rmc(const nmea_parser_t *p, nmea_rmc_t *out);
int nmea_vtg(const nmea_parser_t *p, nmea_vtg_t *out);

#endif /* NMEA_H */
