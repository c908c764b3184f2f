"""Device facts as data, shared by each driver and its mock: the MX-64 control tables and error
codes (:mod:`.dynamixel`), the scale sketch's line format (:mod:`.scale`), GRBL 1.1's line formats,
error and alarm tables (:mod:`.grbl`), UVC control names (:mod:`.camera`).

The wire codecs are not here: the driver speaks through dynamixel-sdk and pyserial, the mock parses
bytes itself, so a codec bug cannot hide on both sides. Modules here import only :mod:`tactile_rig.core`.
"""
