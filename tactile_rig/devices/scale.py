"""Line-format facts of the Arduino HX711 scale, shared by the driver and the mock as data.

Our sketch (``firmware/arduino_scale/arduino_scale.ino``) prints framed machine lines at 57600 baud,
each ``<body>*<CC>\\r\\n`` where ``CC`` is the CRC-8 (polynomial 0x07, init 0, two upper-case hex
digits) of the ASCII body::

    B,hx711-scale,<fw>,<sps>,<cal_factor>*CC     boot banner (also the answer to ``?``, tagged I)
    S,<seq>,<grams>,<raw>*CC                     one sample: seq mod 65536, grams (3 dp), smoothed raw
                                                 counts, absolute (the sketch's tare not subtracted)
    T,ok*CC                                      tare done (answer to ``t``)
    K,<cal_factor>*CC                            calibration done and stored in EEPROM (``c,<grams>``)
    E,<code>,<text>*CC                           a command failed (or E,4: the HX711 is silent)

The stock HX711_ADC example ``Read_1x_load_cell.ino`` prints ``Load_cell output val: 123.45``
(Serial.println of a float: two decimals) after ``Starting...`` / ``Startup is complete``, and
``Tare complete`` after ``t``; the driver reads that too. The wire codecs (CRC, parsing, printing)
are written separately on each side so that one bug cannot hide on both.
"""

from __future__ import annotations

BAUD = 57600
FIRMWARE_NAME = "hx711-scale"
FIRMWARE_VERSION = "1.1.0"  # firmware/arduino_scale/arduino_scale.ino
SEQ_MODULO = 65536
CRC8_POLY = 0x07
RAW_MIN = -(1 << 23)  # HX711 two's complement, 24 bits: saturates at 0x800000 / 0x7FFFFF
RAW_MAX = (1 << 23) - 1
RATES_SPS = (10, 80)  # the HX711's RATE pin: low 10, high 80 samples per second
SMOOTHING_SAMPLES = 16  # HX711_ADC config.h SAMPLES (plus one high and one low value ignored)
DEFAULT_CAL_FACTOR = 696.0  # counts per gram in the HX711_ADC examples
#: standard gravity (CGPM 1901), the one constant that turns a mass on the scale into a force
STANDARD_GRAVITY_MPS2 = 9.80665

TAG_BANNER = "B"
TAG_ID = "I"
TAG_SAMPLE = "S"
TAG_TARE = "T"
TAG_CAL = "K"
TAG_ERROR = "E"

CMD_TARE = b"t\n"
CMD_ID = b"?\n"
CMD_CALIBRATE_PREFIX = b"c,"  # c,<known mass in grams>\n

# Errors the sketch reports with E,<code>,<text>
ERRORS = {
    1: "unknown command",
    2: "known mass must be a positive number of grams",
    3: "load too small to calibrate (check the mass is on the scale)",
    4: "HX711 not responding (check wiring)",
    5: "calibration factor out of range (check the known mass)",
}

# Stock HX711_ADC Read_1x_load_cell example output.
STOCK_DATA_PREFIX = "Load_cell output val: "
STOCK_STARTING = "Starting..."
STOCK_STARTUP_DONE = "Startup is complete"
STOCK_TARE_DONE = "Tare complete"
STOCK_TIMEOUT = "Timeout, check MCU>HX711 wiring and pin designations"
