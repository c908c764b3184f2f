"""tactile_rig.perception.fingervision."""
