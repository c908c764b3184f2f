"""tactile_rig.rig."""
