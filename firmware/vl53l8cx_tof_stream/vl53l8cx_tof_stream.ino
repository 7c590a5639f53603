/*
 * vl53l8cx_tof_stream: streams VL53L8CX frames to a PC as `$TOF` lines for lrnbv_drake's
 * SerialToFSensor (the protocol is in docs/serial-protocol.md).
 *
 * Configuration, chosen to match the simulated sensor (lrnbv_drake/sensor.py):
 *   - 8x8 zones at 15 Hz (the 8x8 maximum), continuous ranging mode;
 *   - target order CLOSEST: the simulator reports the nearest sizeable surface in each zone,
 *     while the ULD's default (STRONGEST) may report a brighter surface behind it;
 *   - sharpener 0 %, one target per zone (VL53L8CX_NB_TARGET_PER_ZONE = 1, the default).
 * Lines carry the ULD's raw zone order; the host remaps it (ZoneGeometry flips).
 *
 * Host -> board commands, one ASCII line each, answered by one `OK ...` or `ERR ...` line:
 *   RES 16|64, FREQ <Hz>, ORDER CLOSEST|STRONGEST, SHARP <0-99>, START, STOP, INFO.
 *
 * Wiring (ST's VL53L8CX-SATEL on a Nucleo, as in ST's HelloWorld example): LPn to A3, PWREN to
 * D11, SDA/SCL to D14/D15, SPI_I2C_N to GND.
 *
 * Build with ST's "STM32duino VL53L8CX" library (2.x: `init()`) and the framing code, with
 * the outputs the host does not use switched off in the library and the sketch alike (they
 * change the layout of VL53L8CX_ResultsData, so both must see the same macros):
 *   FLAGS="-DVL53L8CX_DISABLE_AMBIENT_PER_SPAD -DVL53L8CX_DISABLE_NB_SPADS_ENABLED \
 *       -DVL53L8CX_DISABLE_SIGNAL_PER_SPAD -DVL53L8CX_DISABLE_REFLECTANCE_PERCENT \
 *       -DVL53L8CX_DISABLE_MOTION_INDICATOR"
 *   arduino-cli compile --fqbn <your board> --library firmware/tof_frame \
 *       --build-property "compiler.c.extra_flags=$FLAGS" \
 *       --build-property "compiler.cpp.extra_flags=$FLAGS" firmware/vl53l8cx_tof_stream
 * (in the Arduino IDE, copy firmware/tof_frame into your sketchbook's libraries folder and
 * uncomment the same macros in the library's platform configuration header). An 8x8 read-out
 * is then about 460 bytes instead of 1.4 kB: about 10 ms on I2C at 400 kHz instead of 32 ms.
 * Not compiled here (no Arduino toolchain on the development machine): check the build.
 */
#include <Arduino.h>
#include <Wire.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <vl53l8cx.h>
#include <tof_frame.h>

#if defined(VL53L8CX_DISABLE_DISTANCE_MM) || defined(VL53L8CX_DISABLE_TARGET_STATUS) || \
    defined(VL53L8CX_DISABLE_RANGE_SIGMA_MM) || defined(VL53L8CX_DISABLE_NB_TARGET_DETECTED)
/* Without nb_target_detected the ULD cannot mark empty zones with status 255. */
#error "the $TOF stream needs distance, status, sigma and nb_target_detected outputs enabled"
#endif
#if !defined(VL53L8CX_DISABLE_AMBIENT_PER_SPAD) || !defined(VL53L8CX_DISABLE_NB_SPADS_ENABLED) || \
    !defined(VL53L8CX_DISABLE_SIGNAL_PER_SPAD) || !defined(VL53L8CX_DISABLE_REFLECTANCE_PERCENT) || \
    !defined(VL53L8CX_DISABLE_MOTION_INDICATOR)
#warning "outputs the host does not use are read out too (3 times the I2C traffic); see the build"
#endif
#if defined(ARDUINO_ARCH_STM32)
#include <IWatchdog.h>
/* The library retries a NACKed I2C transfer forever: the watchdog turns that silence into a
 * reset, which the next boot reports with an ERR line. Armed after init(), which uploads the
 * sensor firmware in one call of about 2 s. */
#define WATCHDOG_US 500000
#endif

#define SerialPort Serial
#define DEV_I2C Wire
/* Ignored by boards with native USB CDC; >= 460800 for 8x8 at 15 Hz over a UART bridge. */
#define TOF_BAUD 460800
#define LPN_PIN A3
/* -1 if the board has no PWREN line. */
#define PWREN_PIN 11
/* 1 MHz (Fast-mode Plus) shortens the firmware upload in init() where the MCU supports it.
 * The library's NACK recovery re-begins the bus at the default 100 kHz (a read-out then takes
 * longer than a frame period): restore_clock() sets this again after every frame and error. */
#define I2C_CLOCK_HZ 400000

struct Settings {
  uint8_t resolution;   /* VL53L8CX_RESOLUTION_4X4 (16) or _8X8 (64) */
  uint8_t frequency_hz; /* 1-15 at 8x8, 1-60 at 4x4 */
  uint8_t target_order; /* VL53L8CX_TARGET_ORDER_CLOSEST or _STRONGEST */
  uint8_t sharpener;    /* percent, 0-99 */
};

static VL53L8CX sensor(&DEV_I2C, LPN_PIN);
static VL53L8CX_ResultsData results;
static Settings wanted = {VL53L8CX_RESOLUTION_8X8, 15, VL53L8CX_TARGET_ORDER_CLOSEST, 0};
static Settings applied; /* read back from the device after the last configuration */
static bool streaming = false;
static uint32_t sequence = 0; /* the first frame is 1; 0 never appears on the wire */

static char line[TOF_FRAME_MAX_LINE];
static int16_t distance_mm[VL53L8CX_RESOLUTION_8X8];
static uint8_t target_status[VL53L8CX_RESOLUTION_8X8];
static uint16_t sigma_mm[VL53L8CX_RESOLUTION_8X8];
static char command[32];
static size_t command_len = 0;
static bool command_overflow = false;

/* Prints one reply line. Replies never start with '$', so the host's frame parser skips them. */
static void reply(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void reply(const char *fmt, ...)
{
  char text[192];
  va_list args;
  va_start(args, fmt);
  vsnprintf(text, sizeof text, fmt, args);
  va_end(args);
  SerialPort.print(text);
  SerialPort.print("\r\n");
}

/* Sets the I2C clock again: cheap between transfers, and undoes a NACK recovery's 100 kHz. */
static void restore_clock(void)
{
  DEV_I2C.setClock(I2C_CLOCK_HZ);
}

static uint8_t max_frequency_hz(uint8_t resolution)
{
  return resolution == VL53L8CX_RESOLUTION_8X8 ? 15 : 60;
}

/* Applies `wanted` with ranging stopped (the ULD refuses changes while streaming) and reads
 * the values back. The frequency is set after the resolution because its limit depends on it.
 * Returns the first ULD error, 0 if none. */
static uint8_t configure(void)
{
  bool was_streaming = streaming;
  uint8_t status = 0;
  if (was_streaming) {
    status |= sensor.stop_ranging();
    streaming = false;
  }
  status |= sensor.set_resolution(wanted.resolution);
  status |= sensor.set_ranging_frequency_hz(wanted.frequency_hz);
  status |= sensor.set_ranging_mode(VL53L8CX_RANGING_MODE_CONTINUOUS);
  status |= sensor.set_target_order(wanted.target_order);
  status |= sensor.set_sharpener_percent(wanted.sharpener);
  status |= sensor.get_resolution(&applied.resolution);
  status |= sensor.get_ranging_frequency_hz(&applied.frequency_hz);
  status |= sensor.get_target_order(&applied.target_order);
  status |= sensor.get_sharpener_percent(&applied.sharpener);
  if (was_streaming) {
    status |= sensor.start_ranging();
    streaming = true;
  }
  return status;
}

static void reply_configured(const char *what, uint8_t status)
{
  if (status) {
    restore_clock();
    reply("ERR %s: ULD status %u", what, (unsigned)status);
  } else {
    reply("OK %s", what);
  }
}

static void print_info(void)
{
  reply("OK INFO fw=vl53l8cx_tof_stream proto=%d uld=%s addr=0x%02X res=%u freq=%u order=%s "
        "sharp=%u mode=CONTINUOUS targets=%d streaming=%d seq=%lu",
        TOF_FRAME_VERSION, VL53L8CX_API_REVISION, (unsigned)VL53L8CX_DEFAULT_I2C_ADDRESS,
        (unsigned)applied.resolution, (unsigned)applied.frequency_hz,
        applied.target_order == VL53L8CX_TARGET_ORDER_CLOSEST ? "CLOSEST" : "STRONGEST",
        (unsigned)applied.sharpener, (int)VL53L8CX_NB_TARGET_PER_ZONE, streaming ? 1 : 0,
        (unsigned long)sequence);
}

/* Parses "<NAME> <integer>" arguments; false if there is no integer or it is out of range. */
static bool integer_argument(const char *text, long low, long high, long *value)
{
  char *end = NULL;
  long v = strtol(text, &end, 10);
  if (end == text || *end != '\0' || v < low || v > high) {
    return false;
  }
  *value = v;
  return true;
}

static void handle_command(const char *cmd)
{
  long value = 0;
  if (strncmp(cmd, "RES ", 4) == 0) {
    if (!integer_argument(cmd + 4, 16, 64, &value) || (value != 16 && value != 64)) {
      reply("ERR RES expects 16 or 64");
      return;
    }
    wanted.resolution = (uint8_t)value;
    if (wanted.frequency_hz > max_frequency_hz(wanted.resolution)) {
      wanted.frequency_hz = max_frequency_hz(wanted.resolution);
    }
    reply_configured(cmd, configure());
  } else if (strncmp(cmd, "FREQ ", 5) == 0) {
    if (!integer_argument(cmd + 5, 1, max_frequency_hz(wanted.resolution), &value)) {
      reply("ERR FREQ expects 1 to %u Hz at res %u", (unsigned)max_frequency_hz(wanted.resolution),
            (unsigned)wanted.resolution);
      return;
    }
    wanted.frequency_hz = (uint8_t)value;
    reply_configured(cmd, configure());
  } else if (strcmp(cmd, "ORDER CLOSEST") == 0 || strcmp(cmd, "ORDER STRONGEST") == 0) {
    wanted.target_order = strcmp(cmd + 6, "CLOSEST") == 0 ? VL53L8CX_TARGET_ORDER_CLOSEST
                                                          : VL53L8CX_TARGET_ORDER_STRONGEST;
    reply_configured(cmd, configure());
  } else if (strncmp(cmd, "SHARP ", 6) == 0) {
    if (!integer_argument(cmd + 6, 0, 99, &value)) {
      reply("ERR SHARP expects 0 to 99 (percent)");
      return;
    }
    wanted.sharpener = (uint8_t)value;
    reply_configured(cmd, configure());
  } else if (strcmp(cmd, "START") == 0) {
    uint8_t status = streaming ? 0 : sensor.start_ranging();
    streaming = streaming || status == 0;
    reply_configured(cmd, status);
  } else if (strcmp(cmd, "STOP") == 0) {
    uint8_t status = streaming ? sensor.stop_ranging() : 0;
    streaming = false;
    reply_configured(cmd, status);
  } else if (strcmp(cmd, "INFO") == 0) {
    print_info();
  } else {
    reply("ERR unknown command '%s'", cmd);
  }
}

/* Collects host bytes into lines without blocking the ranging loop. */
static void poll_commands(void)
{
  while (SerialPort.available() > 0) {
    char c = (char)SerialPort.read();
    if (c == '\r' || c == '\n') {
      if (command_overflow) {
        reply("ERR command longer than %u bytes", (unsigned)(sizeof command - 1));
      } else if (command_len > 0) {
        command[command_len] = '\0';
        handle_command(command);
      }
      command_len = 0;
      command_overflow = false;
    } else if (command_len + 1 < sizeof command) {
      command[command_len++] = c;
    } else {
      command_overflow = true;
    }
  }
}

/* Sends the newest frame, if the sensor has one. */
static void poll_frame(void)
{
  uint8_t ready = 0;
  uint8_t status = sensor.check_data_ready(&ready);
  if (status != 0) {
    restore_clock();
    static uint32_t reported_ms = 0; /* polled continuously: say it once a second */
    if (millis() - reported_ms >= 1000) {
      reported_ms = millis();
      reply("ERR check_data_ready: ULD status %u", (unsigned)status);
    }
    return;
  }
  if (!ready) {
    return;
  }
  /* Latched at data-ready, not at the end of integration: the host compares t_us between
   * frames and with the arm's stop time, and the offset is the same for every frame. */
  uint32_t t_us = (uint32_t)micros();
  status = sensor.get_ranging_data(&results);
  restore_clock();
  if (status != 0) {
    reply("ERR get_ranging_data: ULD status %u", (unsigned)status);
    return;
  }
  uint8_t n = applied.resolution;
  /* Results are zone-major, VL53L8CX_NB_TARGET_PER_ZONE slots per zone; slot 0 is the first
   * target in the configured order. The ULD writes status 255 where no target was found. */
  for (uint8_t i = 0; i < n; i++) {
    distance_mm[i] = results.distance_mm[VL53L8CX_NB_TARGET_PER_ZONE * i];
    target_status[i] = results.target_status[VL53L8CX_NB_TARGET_PER_ZONE * i];
    sigma_mm[i] = results.range_sigma_mm[VL53L8CX_NB_TARGET_PER_ZONE * i];
  }
  size_t len = tof_frame_format(line, sizeof line, ++sequence, t_us, n, distance_mm,
                                target_status, sigma_mm);
  if (len > 0) {
    SerialPort.write((const uint8_t *)line, len);
  }
}

void setup()
{
  if (PWREN_PIN >= 0) {
    pinMode(PWREN_PIN, OUTPUT);
    digitalWrite(PWREN_PIN, HIGH);
    delay(10);
  }
  SerialPort.begin(TOF_BAUD);
  DEV_I2C.begin();
  DEV_I2C.setClock(I2C_CLOCK_HZ);

#if defined(ARDUINO_ARCH_STM32)
  if (IWatchdog.isReset(true)) {
    reply("ERR i2c: the sensor stopped answering (a NACK retried without end); the board "
          "was reset by its watchdog");
  }
#endif
  sensor.begin();
  /* Uploads about 86 kB of sensor firmware: about 2 s at 400 kHz (the host allows 5 s). */
  uint8_t status = sensor.init();
  restore_clock();
  if (status != 0) {
    /* Keep saying why, so that a host that opens the port later still sees it. */
    for (;;) {
      reply("ERR init: ULD status %u (check wiring, LPn and power)", (unsigned)status);
      delay(1000);
    }
  }
  status = configure();
  if (status == 0) {
    status = sensor.start_ranging();
    streaming = status == 0;
  }
  reply_configured("BOOT", status);
  print_info();
#if defined(ARDUINO_ARCH_STM32)
  IWatchdog.begin(WATCHDOG_US);
#endif
}

void loop()
{
#if defined(ARDUINO_ARCH_STM32)
  IWatchdog.reload();
#endif
  poll_commands();
  if (streaming) {
    poll_frame();
  }
}
