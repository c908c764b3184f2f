"""tactile_rig.drivers.dynamixel."""
