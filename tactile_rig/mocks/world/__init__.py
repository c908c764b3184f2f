"""tactile_rig.mocks.world."""
