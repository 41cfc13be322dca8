/**
 * @file text.h
 * @brief Building short texts (LOG lines) without a C library: bounded, always terminated.
 */
#ifndef TEXT_H
#define TEXT_H

#include <stddef.h>
#include <stdint.h>

/** A text being built in a caller's buffer. All members are private. */
typedef struct {
    char *buf;
    size_t cap; /**< buffer size, terminator included (at least 1) */
    size_t len;
} text_t;

/** @brief Start an empty text in `buf` (`cap` >= 1 bytes). */
void text_start(text_t *t, char *buf, size_t cap);

/** @brief Append a string; what does not fit is cut. */
void text_add(text_t *t, const char *s);

/** @brief Append an unsigned decimal number. */
void text_add_uint(text_t *t, uint32_t value);

/** @brief Append a byte as two hexadecimal digits with a 0x prefix. */
void text_add_hex8(text_t *t, uint8_t value);

/** @brief The terminated text. */
const char *text_end(text_t *t);

/** @brief Length of a terminated string. */
size_t text_length(const char *s);

/** @brief 1 when two terminated strings are equal. */
int text_equal(const char *a, const char *b);

#endif /* TEXT_H */
