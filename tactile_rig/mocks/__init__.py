"""tactile_rig.mocks."""
