/*
 * arduino_scale.ino — the tactile-rig load-cell scale: HX711 + load cell on an Arduino Uno/Nano.
 *
 * No third-party library: the sketch clocks the HX711 itself. Wiring: HX711 DOUT -> D4,
 * SCK -> D5, VCC -> 5V, GND -> GND. The HX711's RATE pin picks 10 samples/s (low) or 80 (high);
 * the sketch measures which at start-up and reports it, so nothing needs editing to match.
 *
 * Serial protocol (57600 8N1; every line is <body>*<CC>\r\n, CC = CRC-8 poly 0x07, init 0, of the
 * body, two upper-case hex digits). The host driver is tactile_rig/drivers/scale.py; the line
 * facts are in tactile_rig/drivers/scale_protocol.py.
 *
 *   boot     B,hx711-scale,<fw>,<sps>,<cal>     once the HX711 answers and the start-up tare is done
 *   sample   S,<seq>,<grams>,<raw>               one per conversion; seq counts mod 65536 from 0 at
 *                                                boot; grams with 3 decimals; raw = smoothed ABSOLUTE
 *                                                counts (the tare is NOT subtracted), so a host can keep
 *                                                its own zero across a reboot of this board
 *   't\n'    -> T,ok                             tare, answered after the window has refilled
 *   'c,<g>\n'-> K,<cal>                          calibrate with <g> grams on the tared scale (digits,
 *                                                optionally '.' and 1-3 decimals; 0 < g <= 1000000),
 *                                                answered after the window has refilled; saved in EEPROM
 *   '?\n'    -> I,hx711-scale,<fw>,<sps>,<cal>
 *   errors   E,<code>,<text>                     1 unknown command (also a line longer than 32 bytes),
 *                                                2 bad mass, 3 load too small to calibrate,
 *                                                4 HX711 not responding (once a second while silent),
 *                                                5 calibration factor out of range
 *
 * <cal> is counts per gram with 3 decimals. Arithmetic is integer (milligrams, milli-counts per
 * gram, rounded half away from zero) so every value is exact and reproducible off the board.
 *
 * Why framed lines: the host must tell a dropped or corrupted sample from a real one (sequence
 * numbers show drops and resets, the CRC catches line noise), and must recognise a reboot (the
 * banner; an Uno resets whenever the port is opened, because DTR pulses its reset pin).
 *
 * Timing, as the host sees it after a reset: the bootloader (~1.4 s on an Uno), then the HX711 is
 * reset (its first conversion comes 4 periods later, once its filter has settled), 2 conversions
 * are discarded (they also give the rate), 18 fill the smoothing window for the start-up tare, then
 * the banner: ~0.29 s of sketch start-up at 80 samples/s, ~2.3 s at 10. Bytes the host sends meanwhile
 * wait in the core's 64-byte receive buffer (63 usable) and are acted on after the banner; what
 * does not fit is lost, as on any Arduino.
 */

#include <EEPROM.h>
#include <avr/sleep.h>
#include <avr/interrupt.h>

#define FW_VERSION "1.1.0"
#define BAUD 57600
#define PIN_DOUT 4
#define PIN_SCK 5
#define HX711_EXTRA_PULSES 1      // after the 24 data bits: 1 = channel A gain 128, 2 = B/32, 3 = A/64
#define HX711_TIMEOUT_MS 1000     // no conversion for this long: the HX711 is not answering
#define SETTLE_CONVERSIONS 2      // discarded after an HX711 reset; the first two also give its rate
#define SAMPLES 16                // averaged, after dropping the highest and the lowest (as HX711_ADC)
#define WINDOW (SAMPLES + 2)
#define LINE_MAX 32               // longest command line accepted
#define EEPROM_ADDR 0
#define EEPROM_MAGIC 0x5CA1E011UL // marks a stored calibration (milli-counts per gram, CRC-8 checked)
#define DEFAULT_CAL_MILLI 696000L // 696.000 counts per gram, HX711_ADC's example value
#define CAL_MILLI_MIN 100L        // 0.1 counts per gram
#define CAL_MILLI_MAX 100000000L  // 100000 counts per gram
#define MIN_CAL_COUNTS 100L       // a calibration mass must move the reading at least this much
#define MASS_G_MAX 1000000L       // 1 t

static long window[WINDOW];       // the last WINDOW conversions, absolute counts
static uint8_t winPos = 0;
static long smoothed = 0;         // mean of the window without its extremes, absolute counts
static long tareCounts = 0;
static long calMilli = DEFAULT_CAL_MILLI;
static uint8_t rateSps = 0;
static uint16_t seq = 0;
static uint8_t tareLeft = 0;      // conversions until a requested tare is taken
static uint8_t calLeft = 0;       // conversions until a requested calibration is taken
static long calMassMg = 0;
static char line[LINE_MAX + 1];
static uint8_t lineLen = 0;
static bool lineBad = false;      // too long, or a NUL byte: answered with E,1 at its newline
static unsigned long lastConversionMs = 0;

struct Stored {
  uint32_t magic;
  int32_t calMilli;
  uint8_t crc;
};

// ---- wire format ---------------------------------------------------------------------------

static uint8_t crc8(const uint8_t *p, uint8_t n) {
  uint8_t crc = 0;
  while (n--) {
    crc ^= *p++;
    for (uint8_t i = 0; i < 8; i++) {
      crc = (crc & 0x80) ? (uint8_t)((crc << 1) ^ 0x07) : (uint8_t)(crc << 1);
    }
  }
  return crc;
}

// n / d rounded half away from zero (d != 0); the host's emulation uses the same rule.
static int64_t divRound(int64_t n, int64_t d) {
  if (d < 0) {
    n = -n;
    d = -d;
  }
  return n >= 0 ? (n + d / 2) / d : -((-n + d / 2) / d);
}

static char *putStr(char *p, const char *s) {
  while (*s) *p++ = *s++;
  return p;
}

static char *putStrP(char *p, PGM_P s) {
  char c;
  while ((c = (char)pgm_read_byte(s++)) != 0) *p++ = c;
  return p;
}

static char *putLong(char *p, long v) {
  ltoa(v, p, 10);
  while (*p) p++;
  return p;
}

// A value in thousandths, printed with 3 decimals ("-0.250", "696.000").
static char *putMilli(char *p, int64_t v) {
  if (v < 0) {
    *p++ = '-';
    v = -v;
  }
  uint16_t frac = (uint16_t)(v % 1000);
  ultoa((unsigned long)(v / 1000), p, 10);
  while (*p) p++;
  *p++ = '.';
  *p++ = (char)('0' + frac / 100);
  *p++ = (char)('0' + frac / 10 % 10);
  *p++ = (char)('0' + frac % 10);
  return p;
}

// Send buf[0..end) as one framed line: body*CC\r\n.
static void sendFramed(char *buf, char *end) {
  static const char hex[] = "0123456789ABCDEF";
  uint8_t c = crc8((const uint8_t *)buf, (uint8_t)(end - buf));
  *end++ = '*';
  *end++ = hex[c >> 4];
  *end++ = hex[c & 0x0F];
  *end++ = '\r';
  *end++ = '\n';
  Serial.write((const uint8_t *)buf, end - buf);
}

static const char ERR_1[] PROGMEM = "unknown command";
static const char ERR_2[] PROGMEM = "known mass must be a positive number of grams";
static const char ERR_3[] PROGMEM = "load too small to calibrate (check the mass is on the scale)";
static const char ERR_4[] PROGMEM = "HX711 not responding (check wiring)";
static const char ERR_5[] PROGMEM = "calibration factor out of range (check the known mass)";
static PGM_P const ERRORS[] PROGMEM = {ERR_1, ERR_2, ERR_3, ERR_4, ERR_5};

static void sendError(uint8_t code) {
  char buf[80];
  char *p = putStr(buf, "E,");
  *p++ = (char)('0' + code);
  *p++ = ',';
  p = putStrP(p, (PGM_P)pgm_read_word(&ERRORS[code - 1]));
  sendFramed(buf, p);
}

static void sendId(char tag) {
  char buf[48];
  char *p = buf;
  *p++ = tag;
  p = putStr(p, ",hx711-scale," FW_VERSION ",");
  p = putLong(p, rateSps);
  *p++ = ',';
  p = putMilli(p, calMilli);
  sendFramed(buf, p);
}

static void sendSample(int64_t milligrams) {
  char buf[48];
  char *p = putStr(buf, "S,");
  p = putLong(p, (long)seq);
  *p++ = ',';
  p = putMilli(p, milligrams);
  *p++ = ',';
  p = putLong(p, smoothed);
  sendFramed(buf, p);
  seq++;  // wraps at 65536; the host counts gaps modulo that
}

// ---- EEPROM ---------------------------------------------------------------------------------

static void loadCalibration() {
  Stored st;
  EEPROM.get(EEPROM_ADDR, st);
  long v = st.calMilli;
  bool inRange = (v >= CAL_MILLI_MIN && v <= CAL_MILLI_MAX) || (v <= -CAL_MILLI_MIN && v >= -CAL_MILLI_MAX);
  if (st.magic == EEPROM_MAGIC && st.crc == crc8((const uint8_t *)&st, 8) && inRange) {
    calMilli = v;
  }
}

static void saveCalibration() {
  Stored st;
  st.magic = EEPROM_MAGIC;
  st.calMilli = calMilli;
  st.crc = crc8((const uint8_t *)&st, 8);
  EEPROM.put(EEPROM_ADDR, st);  // put() writes only the bytes that changed: little EEPROM wear
}

// ---- the HX711 ------------------------------------------------------------------------------

static void idle() {
  // Sleep until an interrupt: a byte from the host, DOUT changing (pin-change interrupt), the
  // 1 ms millis() tick or the transmitter. Idle mode keeps timers and the UART running, so this
  // only saves power; it also keeps the simulated board cheap to run in real time.
  set_sleep_mode(SLEEP_MODE_IDLE);
  cli();
  if (digitalRead(PIN_DOUT) == HIGH && !Serial.available()) {
    sleep_enable();
    sei();
    sleep_cpu();  // the instruction after sei runs before any pending interrupt: no lost wake-up
    sleep_disable();
  }
  sei();
}

// Nothing to do in the handlers: a pin change only has to wake the CPU from idle().
EMPTY_INTERRUPT(PCINT0_vect);
#ifdef PCINT1_vect
EMPTY_INTERRUPT(PCINT1_vect);
#endif
#ifdef PCINT2_vect
EMPTY_INTERRUPT(PCINT2_vect);
#endif

static bool hxReady() {
  return digitalRead(PIN_DOUT) == LOW;  // DOUT low: a conversion is waiting
}

// Shift one conversion out (call only when hxReady()): 24 bits MSB first, then the extra pulses
// that choose the channel and gain of the next conversion.
static long hxRead() {
  uint32_t v = 0;
  for (uint8_t i = 0; i < 24 + HX711_EXTRA_PULSES; i++) {
    // SCK high must stay under 50 us (over 60 us powers the HX711 down): no interrupt in between.
    uint8_t sreg = SREG;
    cli();
    digitalWrite(PIN_SCK, HIGH);
    delayMicroseconds(1);  // DOUT is valid 0.1 us after the rising edge; high time >= 0.2 us
    uint8_t bit = digitalRead(PIN_DOUT);
    digitalWrite(PIN_SCK, LOW);
    SREG = sreg;
    delayMicroseconds(1);  // low time >= 0.2 us
    if (i < 24) v = (v << 1) | bit;
  }
  if (v & 0x800000UL) v |= 0xFF000000UL;  // 24-bit two's complement
  return (long)v;
}

// Reset the HX711: SCK high for over 60 us powers it down, low again restarts it on channel A,
// gain 128. Its first conversion then comes once its filter has settled (4 periods).
static void hxReset() {
  digitalWrite(PIN_SCK, HIGH);
  delayMicroseconds(100);
  digitalWrite(PIN_SCK, LOW);
}

static void computeSmoothed() {
  long sum = 0, lo = window[0], hi = window[0];
  for (uint8_t i = 0; i < WINDOW; i++) {
    long v = window[i];
    sum += v;
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  smoothed = (long)divRound(sum - lo - hi, SAMPLES);
}

// Wait for the next conversion; false after HX711_TIMEOUT_MS without one.
static bool nextConversion(long *out) {
  unsigned long t0 = millis();
  while (!hxReady()) {
    if (millis() - t0 >= HX711_TIMEOUT_MS) return false;
    idle();
  }
  *out = hxRead();
  return true;
}

// Reset the HX711, measure its rate and take the start-up tare; false if it does not answer.
static bool startHx711() {
  long v;
  hxReset();
  unsigned long t1 = 0;
  for (uint8_t i = 0; i < SETTLE_CONVERSIONS; i++) {
    if (!nextConversion(&v)) return false;
    unsigned long now = micros();
    if (i == SETTLE_CONVERSIONS - 1) rateSps = (now - t1 < 40000UL) ? 80 : 10;  // 12.5 ms or 100 ms
    t1 = now;
  }
  for (uint8_t i = 0; i < WINDOW; i++) {
    if (!nextConversion(&window[i])) return false;
  }
  winPos = 0;
  computeSmoothed();
  tareCounts = smoothed;
  lastConversionMs = millis();
  return true;
}

// ---- commands -------------------------------------------------------------------------------

// "<digits>[.<1-3 digits>]" grams -> milligrams; false for anything else, zero or over MASS_G_MAX.
static bool parseMassMg(const char *s, long *mg) {
  long whole = 0, frac = 0;
  uint8_t nd = 0, nf = 0;
  while (*s >= '0' && *s <= '9') {
    whole = whole * 10 + (*s++ - '0');
    if (++nd > 7) return false;
  }
  if (nd == 0) return false;
  if (*s == '.') {
    s++;
    while (*s >= '0' && *s <= '9') {
      frac = frac * 10 + (*s++ - '0');
      if (++nf > 3) return false;
    }
    if (nf == 0) return false;
  }
  if (*s != 0 || whole > MASS_G_MAX) return false;
  while (nf++ < 3) frac *= 10;
  *mg = whole * 1000L + frac;
  return *mg > 0 && *mg <= MASS_G_MAX * 1000L;
}

static void handleLine(const char *s) {
  if (strcmp(s, "t") == 0) {
    tareLeft = WINDOW;  // let the window refill with what is on the scale now
  } else if (strcmp(s, "?") == 0) {
    sendId('I');
  } else if (s[0] == 'c' && s[1] == ',') {
    long mg;
    if (!parseMassMg(s + 2, &mg)) {
      sendError(2);
    } else {
      calMassMg = mg;
      calLeft = WINDOW;
    }
  } else {
    sendError(1);
  }
}

static void readCommands() {
  while (Serial.available() > 0) {
    char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      if (lineBad) {
        sendError(1);
      } else if (lineLen) {
        line[lineLen] = 0;
        handleLine(line);
      }
      lineLen = 0;
      lineBad = false;
    } else if (ch == 0 || lineLen >= LINE_MAX) {
      lineBad = true;
    } else {
      line[lineLen++] = ch;
    }
  }
}

// ---- one conversion ---------------------------------------------------------------------------

static void onConversion(long raw) {
  lastConversionMs = millis();
  window[winPos] = raw;
  winPos = (uint8_t)((winPos + 1) % WINDOW);
  computeSmoothed();
  if (tareLeft && --tareLeft == 0) {
    tareCounts = smoothed;
    char buf[12];
    sendFramed(buf, putStr(buf, "T,ok"));
  }
  if (calLeft && --calLeft == 0) {
    int64_t delta = (int64_t)smoothed - tareCounts;
    if (delta < MIN_CAL_COUNTS && delta > -MIN_CAL_COUNTS) {
      sendError(3);
    } else {
      int64_t f = divRound(delta * 1000000LL, calMassMg);
      if ((f < CAL_MILLI_MIN && f > -CAL_MILLI_MIN) || f > CAL_MILLI_MAX || f < -CAL_MILLI_MAX) {
        sendError(5);
      } else {
        calMilli = (long)f;
        saveCalibration();
        char buf[24];
        char *p = putStr(buf, "K,");
        sendFramed(buf, putMilli(p, calMilli));
      }
    }
  }
  sendSample(divRound(((int64_t)smoothed - tareCounts) * 1000000LL, calMilli));
}

// ---- Arduino entry points -----------------------------------------------------------------------

void setup() {
  Serial.begin(BAUD);
  loadCalibration();
  pinMode(PIN_SCK, OUTPUT);
  digitalWrite(PIN_SCK, LOW);
  pinMode(PIN_DOUT, INPUT_PULLUP);  // an unplugged HX711 then reads "busy", not random data
  *digitalPinToPCMSK(PIN_DOUT) |= bit(digitalPinToPCMSKbit(PIN_DOUT));
  *digitalPinToPCICR(PIN_DOUT) |= bit(digitalPinToPCICRbit(PIN_DOUT));
  while (!startHx711()) {
    sendError(4);  // and try again: the HX711 may be plugged in later
  }
  sendId('B');
}

void loop() {
  readCommands();
  if (hxReady()) {
    onConversion(hxRead());
  } else if (millis() - lastConversionMs >= HX711_TIMEOUT_MS) {
    sendError(4);
    lastConversionMs = millis();  // again in a second while it stays silent
  } else {
    idle();
  }
}
