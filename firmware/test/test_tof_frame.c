/*
 * Host test of tof_frame.c, built and run by tests/test_tof_protocol.py.
 *
 * Checks what C alone can check (buffer bounds, rejected resolutions) and prints, one per
 * line, what only the Python side can judge:
 *   CRC <hex of tof_crc16("123456789")>
 *   the 8x8 frame below, formatted
 *   the 4x4 frame below, formatted
 * The Python test rebuilds both frames from the same formulas and parses the lines.
 */
#include <stdio.h>
#include <string.h>

#include "tof_frame.h"

static int failures = 0;

static void check(int ok, const char *what)
{
  if (!ok) {
    fprintf(stderr, "FAIL: %s\n", what);
    failures++;
  }
}

int main(void)
{
  static char line[TOF_FRAME_MAX_LINE];
  int16_t d[64];
  uint8_t s[64];
  uint16_t g[64];

  printf("CRC %04X\n", tof_crc16((const uint8_t *)"123456789", 9));

  /* 8x8: every field type at its extremes. */
  for (int i = 0; i < 64; i++) {
    d[i] = (int16_t)(i * 61 - 500);
    s[i] = (uint8_t)((i * 37) % 256);
    g[i] = (uint16_t)(i * 1040);
  }
  d[0] = -32768;
  d[63] = 32767;
  s[1] = 255;
  g[63] = 65535;
  size_t len = tof_frame_format(line, sizeof line, 4294967295u, 123456789u, 64, d, s, g);
  check(len > 0 && len == strlen(line), "8x8 frame formats");
  fputs(line, stdout);

  /* The widest possible line fits TOF_FRAME_MAX_LINE exactly, and not one byte less. */
  static int16_t dmin[64];
  static uint8_t smax[64];
  static uint16_t gmax[64];
  for (int i = 0; i < 64; i++) {
    dmin[i] = -32768;
    smax[i] = 255;
    gmax[i] = 65535;
  }
  size_t widest = tof_frame_format(line, sizeof line, 4294967295u, 4294967295u, 64, dmin, smax,
                                   gmax);
  check(widest == TOF_FRAME_MAX_LINE - 1, "the widest line needs TOF_FRAME_MAX_LINE bytes");
  check(tof_frame_format(line, sizeof line - 1, 4294967295u, 4294967295u, 64, dmin, smax,
                         gmax) == 0, "a buffer one byte short is refused");
  check(tof_frame_format(line, 0, 1, 0, 16, d, s, g) == 0, "an empty buffer is refused");
  check(tof_frame_format(line, sizeof line, 1, 0, 32, d, s, g) == 0, "n = 32 is refused");

  /* 4x4 */
  for (int i = 0; i < 16; i++) {
    d[i] = (int16_t)(i * 100);
    s[i] = 5;
    g[i] = (uint16_t)i;
  }
  len = tof_frame_format(line, sizeof line, 1u, 0u, 16, d, s, g);
  check(len > 0, "4x4 frame formats");
  fputs(line, stdout);

  return failures ? 1 : 0;
}
