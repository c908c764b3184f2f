"""Byte-free fakes: a simulated gripper and arm and model/rendered tactile sensors that satisfy the
controllers' protocols (``Gripper``, ``Motion``, ``TactileSensor``) without any wire in between."""
