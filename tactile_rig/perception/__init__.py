"""Perception: pure functions and small classes over numpy arrays, with units in every name.

No I/O and no globals here; every speed/accuracy knob is a parameter with a documented default.
"""
