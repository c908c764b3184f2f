"""tactile_rig.testing."""
