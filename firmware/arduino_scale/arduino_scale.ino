/*
 * arduino_scale.ino — the tactile-rig load-cell scale: HX711 + load cell on an Arduino Uno/Nano.
 *
 * Built on the HX711_ADC library (Olav Kallhovd, https://github.com/olkal/HX711_ADC), install it
 * from the Library Manager. Wiring: HX711 DOUT -> D4, SCK -> D5, VCC -> 5V, GND -> GND.
 * Put the HX711's RATE pin high for 80 samples/s (low: 10); set HX711_RATE_SPS below to match.
 *
 * Serial protocol (57600 8N1; every line is <body>*<CC>\r\n, CC = CRC-8 poly 0x07 of the body,
 * two upper-case hex digits). The host driver is tactile_rig/drivers/scale.py; the line facts
 * are in tactile_rig/drivers/scale_protocol.py.
 *
 *   boot     B,hx711-scale,<fw>,<sps>,<cal_factor>      once the load cell is stable and tared
 *   sample   S,<seq>,<grams>,<raw>                       every conversion; seq counts mod 65536,
 *                                                        grams with 3 decimals, raw = smoothed counts
 *   't\n'    -> T,ok                                     after the smoothing window refills
 *   'c,<g>\n'-> K,<cal_factor>                           calibrate with <g> grams on the tared scale;
 *                                                        the factor is saved to EEPROM
 *   '?\n'    -> I,hx711-scale,<fw>,<sps>,<cal_factor>
 *   errors   E,<code>,<text>                             1 unknown command, 2 bad mass,
 *                                                        3 load too small, 4 HX711 not responding
 *
 * Why framed lines: the host must tell a dropped or corrupted sample from a real one (sequence
 * numbers show drops and resets, the CRC catches line noise), and must recognise a reboot (the
 * banner; an Uno resets whenever the port is opened, because DTR pulses its reset pin).
 */

#include <HX711_ADC.h>
#include <EEPROM.h>

#define FW_VERSION "1.0.0"
#define BAUD 57600
#define HX711_RATE_SPS 80          // what the RATE pin is wired for (10 or 80)
#define PIN_DOUT 4
#define PIN_SCK 5
#define EEPROM_MAGIC 0x5CA1E001UL  // marks a stored calibration factor
#define EEPROM_ADDR 0
#define DEFAULT_CAL_FACTOR 696.0   // counts per gram in the HX711_ADC examples
#define SETTLE_MS 500              // stabilising time before the start-up tare
#define WINDOW (SAMPLES + IGN_HIGH_SAMPLE + IGN_LOW_SAMPLE)  // HX711_ADC's smoothing window (config.h)

HX711_ADC LoadCell(PIN_DOUT, PIN_SCK);

static float calFactor = DEFAULT_CAL_FACTOR;
static uint16_t seq = 0;
static char rxLine[40];
static uint8_t rxLen = 0;
static bool tarePending = false;
static uint8_t calCountdown = 0;     // conversions left before a calibration uses the window
static float calMass = 0.0;

struct Stored {
  uint32_t magic;
  float calFactor;
};

static uint8_t crc8(const char *s) {
  uint8_t crc = 0;
  while (*s) {
    crc ^= (uint8_t)*s++;
    for (uint8_t i = 0; i < 8; i++) {
      crc = (crc & 0x80) ? (uint8_t)((crc << 1) ^ 0x07) : (uint8_t)(crc << 1);
    }
  }
  return crc;
}

// Print body*CC\r\n (Serial.println ends lines with \r\n).
static void sendFramed(const char *body) {
  char tail[4];
  uint8_t c = crc8(body);
  const char hex[] = "0123456789ABCDEF";
  tail[0] = '*';
  tail[1] = hex[c >> 4];
  tail[2] = hex[c & 0x0F];
  tail[3] = 0;
  Serial.print(body);
  Serial.println(tail);
}

static void sendError(uint8_t code, const char *text) {
  char body[64];
  snprintf(body, sizeof(body), "E,%u,%s", code, text);
  sendFramed(body);
}

static void sendId(char tag) {
  char body[64], cal[16];
  dtostrf(calFactor, 1, 3, cal);
  snprintf(body, sizeof(body), "%c,hx711-scale," FW_VERSION ",%d,%s", tag, HX711_RATE_SPS, cal);
  sendFramed(body);
}

static void loadCalibration() {
  Stored st;
  EEPROM.get(EEPROM_ADDR, st);
  if (st.magic == EEPROM_MAGIC && st.calFactor == st.calFactor && st.calFactor != 0.0) {  // not NaN
    calFactor = st.calFactor;
  }
}

static void saveCalibration() {
  Stored st = {EEPROM_MAGIC, calFactor};
  EEPROM.put(EEPROM_ADDR, st);  // put() only writes the bytes that changed: EEPROM wear is low
}

static void handleLine(const char *line) {
  if (strcmp(line, "t") == 0) {
    LoadCell.tareNoDelay();
    tarePending = true;
  } else if (strcmp(line, "?") == 0) {
    sendId('I');
  } else if (line[0] == 'c' && line[1] == ',') {
    char *end;
    double mass = strtod(line + 2, &end);
    if (end == line + 2 || !(mass > 0.0)) {
      sendError(2, "known mass must be a positive number of grams");
    } else {
      calMass = (float)mass;
      calCountdown = WINDOW;  // let the smoothing window fill with the mass on the scale
    }
  } else {
    sendError(1, "unknown command");
  }
}

static void readCommands() {
  while (Serial.available()) {
    char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      rxLine[rxLen] = 0;
      if (rxLen) handleLine(rxLine);
      rxLen = 0;
    } else if (rxLen < sizeof(rxLine) - 1) {
      rxLine[rxLen++] = ch;
    } else {
      rxLen = 0;  // an overlong line is noise: drop it
    }
  }
}

void setup() {
  Serial.begin(BAUD);
  loadCalibration();
  LoadCell.begin();
  LoadCell.start(SETTLE_MS, true);  // stabilise, then tare
  if (LoadCell.getTareTimeoutFlag() || LoadCell.getSignalTimeoutFlag()) {
    for (;;) {  // no HX711: say so once a second rather than print nonsense
      sendError(4, "HX711 not responding (check wiring)");
      delay(1000);
    }
  }
  LoadCell.setCalFactor(calFactor);
  sendId('B');
}

void loop() {
  readCommands();
  if (!LoadCell.update()) {
    return;  // update() must run faster than the HX711's rate; nothing new yet
  }
  if (tarePending && LoadCell.getTareStatus()) {
    tarePending = false;
    char body[8] = "T,ok";
    sendFramed(body);
  }
  if (calCountdown && --calCountdown == 0) {
    float smoothedCounts = LoadCell.getData() * calFactor;  // counts above the tare offset
    if (fabs(smoothedCounts) < 100.0) {
      sendError(3, "load too small to calibrate (check the mass is on the scale)");
    } else {
      calFactor = smoothedCounts / calMass;
      LoadCell.setCalFactor(calFactor);
      saveCalibration();
      char body[24], cal[16];
      dtostrf(calFactor, 1, 3, cal);
      snprintf(body, sizeof(body), "K,%s", cal);
      sendFramed(body);
    }
  }
  float grams = LoadCell.getData();
  long raw = (long)(grams * calFactor) + LoadCell.getTareOffset();  // smoothed counts
  char body[48], g[16];
  dtostrf(grams, 1, 3, g);
  snprintf(body, sizeof(body), "S,%u,%s,%ld", seq, g, raw);
  sendFramed(body);
  seq++;  // wraps at 65536; the host counts gaps modulo that
}
