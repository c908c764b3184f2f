"""Sessions on the rig: each drives devices, records what it measured, fits and writes a versioned file.

One module per session: :mod:`.gelsight` (ball presses with the jig), :mod:`.scale` (tare and a known
mass), :mod:`.gripper` (closed and open stops), :mod:`.fingervision` (marker baseline), :mod:`.force_map`
and :mod:`.substance` (the learned fingertip models); and what they share: :mod:`.guide` (the operator's
prompts), :mod:`.session_recording` (the MCAP of a session) and :mod:`.calibration_file` (the JSON
calibration envelope, its report and the stable links). The public faces are
:mod:`tactile_rig.rig.calibration_sessions` and :mod:`tactile_rig.rig.learning`.
"""
