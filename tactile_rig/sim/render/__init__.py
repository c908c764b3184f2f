"""Renderers: GelSight frames (:mod:`.gelsight`) and FingerVision frames (:mod:`.fingervision`) of a world."""
