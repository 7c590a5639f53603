/*
 * tof_frame: formats one VL53L8CX frame as a `$TOF` protocol line (docs/serial-protocol.md).
 *
 * Plain C99 with no stdio and no Arduino dependency, so the same code runs on the MCU and in
 * the host test (firmware/test/test_tof_frame.c) that checks it against the Python parser.
 */
#ifndef TOF_FRAME_H
#define TOF_FRAME_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Protocol version written in every line. */
#define TOF_FRAME_VERSION 1

/* Buffer size that holds any line tof_frame_format writes: every field at its widest with a u32
 * timestamp ("$TOF,1,<10 digits>,<10 digits>,64" + 64 x ",-32768" + 64 x ",255" + 64 x ",65535"
 * + "*FFFF\r\n" = 1126 bytes) plus the NUL. */
#define TOF_FRAME_MAX_LINE 1127

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor), bit by bit: the
 * line rate, not the CRC, limits the frame rate. Check value: "123456789" -> 0x29B1. */
uint16_t tof_crc16(const uint8_t *data, size_t len);

/* Writes `$TOF,1,<seq>,<t_us>,<n>,<n distances>,<n statuses>,<n sigmas>*<CRC>\r\n` and a NUL
 * into buf. `n` is 16 or 64 and the arrays hold one target per zone in the ULD's raw zone
 * order. Returns the line length without the NUL, or 0 (and writes nothing useful) if `n` is
 * not 16 or 64 or the line does not fit in `cap` bytes. */
size_t tof_frame_format(char *buf, size_t cap, uint32_t seq, uint32_t t_us, uint8_t n,
                        const int16_t *distance_mm, const uint8_t *status,
                        const uint16_t *sigma_mm);

#ifdef __cplusplus
}
#endif

#endif /* TOF_FRAME_H */
