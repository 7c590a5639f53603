/* See tof_frame.h. */
#include "tof_frame.h"

uint16_t tof_crc16(const uint8_t *data, size_t len)
{
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < len; i++) {
    crc ^= (uint16_t)((uint16_t)data[i] << 8);
    for (int bit = 0; bit < 8; bit++) {
      crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
  }
  return crc;
}

/* A bounded writer: once a write does not fit, `ok` stays 0 and nothing more is written. */
typedef struct {
  char *buf;
  size_t cap;
  size_t len;
  int ok;
} writer_t;

static void put_char(writer_t *w, char c)
{
  if (w->ok && w->len + 1 < w->cap) { /* keep room for the NUL */
    w->buf[w->len++] = c;
  } else {
    w->ok = 0;
  }
}

static void put_str(writer_t *w, const char *s)
{
  while (*s) {
    put_char(w, *s++);
  }
}

static void put_uint(writer_t *w, uint32_t v)
{
  char digits[10];
  int n = 0;
  do {
    digits[n++] = (char)('0' + v % 10u);
    v /= 10u;
  } while (v);
  while (n) {
    put_char(w, digits[--n]);
  }
}

static void put_int(writer_t *w, int32_t v)
{
  if (v < 0) {
    put_char(w, '-');
    put_uint(w, (uint32_t)(-(int64_t)v));
  } else {
    put_uint(w, (uint32_t)v);
  }
}

size_t tof_frame_format(char *buf, size_t cap, uint32_t seq, uint32_t t_us, uint8_t n,
                        const int16_t *distance_mm, const uint8_t *status,
                        const uint16_t *sigma_mm)
{
  static const char hex[] = "0123456789ABCDEF";
  writer_t w = {buf, cap, 0, cap > 0};
  if (n != 16 && n != 64) {
    return 0;
  }
  put_str(&w, "$TOF,");
  put_uint(&w, TOF_FRAME_VERSION);
  put_char(&w, ',');
  put_uint(&w, seq);
  put_char(&w, ',');
  put_uint(&w, t_us);
  put_char(&w, ',');
  put_uint(&w, n);
  for (uint8_t i = 0; i < n; i++) {
    put_char(&w, ',');
    put_int(&w, distance_mm[i]);
  }
  for (uint8_t i = 0; i < n; i++) {
    put_char(&w, ',');
    put_uint(&w, status[i]);
  }
  for (uint8_t i = 0; i < n; i++) {
    put_char(&w, ',');
    put_uint(&w, sigma_mm[i]);
  }
  if (!w.ok) {
    return 0;
  }
  /* The CRC covers the bytes strictly between '$' and '*'. */
  uint16_t crc = tof_crc16((const uint8_t *)buf + 1, w.len - 1);
  put_char(&w, '*');
  for (int shift = 12; shift >= 0; shift -= 4) {
    put_char(&w, hex[(crc >> shift) & 0xF]);
  }
  put_str(&w, "\r\n");
  if (!w.ok) {
    return 0;
  }
  buf[w.len] = '\0';
  return w.len;
}
