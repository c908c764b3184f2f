"""tactile_rig.mocks.scenes."""
