"""tactile_rig.perception.gelsight."""
