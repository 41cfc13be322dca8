/**
 * @file text.c
 * @brief Bounded text building (see text.h).
 */
#include "text.h"

void text_start(text_t *t, char *buf, size_t cap)
{
    t->buf = buf;
    t->cap = cap;
    t->len = 0;
    buf[0] = '\0';
}

static void add_char(text_t *t, char c)
{
    if (t->len + 1 < t->cap) {
        t->buf[t->len++] = c;
        t->buf[t->len] = '\0';
    }
}

void text_add(text_t *t, const char *s)
{
    while (*s != '\0') {
        add_char(t, *s++);
    }
}

void text_add_uint(text_t *t, uint32_t value)
{
    char digits[10];
    int n = 0;
    do {
        digits[n++] = (char)('0' + value % 10u);
        value /= 10u;
    } while (value != 0);
    while (n > 0) {
        add_char(t, digits[--n]);
    }
}

void text_add_hex8(text_t *t, uint8_t value)
{
    static const char hex[] = "0123456789ABCDEF";
    add_char(t, '0');
    add_char(t, 'x');
    add_char(t, hex[value >> 4]);
    add_char(t, hex[value & 0x0Fu]);
}

const char *text_end(text_t *t)
{
    return t->buf;
}

size_t text_length(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        ++n;
    }
    return n;
}

int text_equal(const char *a, const char *b)
{
    while (*a != '\0' && *a == *b) {
        ++a;
        ++b;
    }
    return *a == *b;
}
