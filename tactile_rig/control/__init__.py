"""tactile_rig.control."""
