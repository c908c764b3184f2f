"""tactile_rig.drivers."""
