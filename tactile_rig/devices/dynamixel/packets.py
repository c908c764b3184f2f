"""Dynamixel packet facts as data: headers, the broadcast ID, instruction codes, and the CRC polynomial.

From the ROBOTIS e-manual (Protocol 2.0 and Protocol 1.0 pages)::

    P2 instruction  FF FF FD 00 | ID | LEN_L LEN_H | INST | params        | CRC_L CRC_H
    P2 status       FF FF FD 00 | ID | LEN_L LEN_H | 55   | ERR | params  | CRC_L CRC_H
    P1 instruction  FF FF | ID | LEN | INST | params | CHK
    P1 status       FF FF | ID | LEN | ERR  | params | CHK

Both wire codecs read these names: the driver's (:mod:`tactile_rig.drivers.dynamixel.wire`, beside
dynamixel-sdk) and the mock firmware's (:mod:`tactile_rig.mocks.dynamixel.codec`). The two codecs
stay separate on purpose, each written from the e-manual, so that a framing, stuffing or CRC bug
cannot hide on both sides of the wire; only these facts are shared.
"""

from __future__ import annotations

P2_HEADER = b"\xff\xff\xfd"
P2_RESERVED = 0x00  #: the byte after the P2 header
P1_HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
#: the instruction byte of a Protocol 2.0 status packet
STATUS_INSTRUCTION = 0x55
#: Protocol 2.0 CRC-16: this polynomial, initial value 0, not reflected, over the stuffed packet
CRC16_POLY = 0x8005

# Instructions (both protocols unless noted)
PING = 0x01
READ = 0x02
WRITE = 0x03
REG_WRITE = 0x04
ACTION = 0x05
FACTORY_RESET = 0x06
REBOOT = 0x08  #: MX firmware 41+ accepts it on Protocol 1.0 too
CLEAR = 0x10  #: Protocol 2.0
SYNC_READ = 0x82  #: Protocol 2.0
SYNC_WRITE = 0x83
FAST_SYNC_READ = 0x8A  #: Protocol 2.0
BULK_READ = 0x92
BULK_WRITE = 0x93  #: Protocol 2.0
FAST_BULK_READ = 0x9A  #: Protocol 2.0

#: Factory Reset options (Protocol 2.0): everything, everything but the ID, everything but ID and baud
RESET_ALL, RESET_ALL_BUT_ID, RESET_ALL_BUT_ID_AND_BAUD = 0xFF, 0x01, 0x02
#: the parameters of Clear that reset the multi-turn position (Protocol 2.0)
CLEAR_MULTI_TURN = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
