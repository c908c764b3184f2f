"""Writes tests/data/recordings/json_session.mcap with the JSON-encoded recorder (jsonschema channels)."""
import numpy as np, cv2
from pathlib import Path
from tactile_rig.core.clock import VirtualClock
from tactile_rig.control.protocols import Pose
from tactile_rig.rig.recording import Recorder

out = Path("tests/data/recordings/json_session.mcap")
clock = VirtualClock()
y, x = np.mgrid[0:24, 0:32]
with Recorder(out, clock=clock, background_flush=False) as rec:
    rec.add_metadata("fixture", {"writer": "JSON-encoded recorder", "frames": 5})
    rec.add_attachment("note.txt", b"fixture", media_type="text/plain")
    for i in range(5):
        clock.advance(0.1)
        img = np.stack([(x * 8 + i * 10) % 256, (y * 10) % 256, np.full_like(x, 40 * i)], -1).astype(np.uint8)
        rec.write_frame("camera_left", img, compress="png")
        rec.write_frame("camera_left", img)
        rec.write_scale(0.5 * i, grams=51.0 * i, raw=1000 + i, seq=i, saturated=False)
        rec.write_jig_pose(Pose(x_mm=1.0 * i, y_mm=-0.5 * i, theta_deg=2.0 * i))
        rec.write_state("gripper", {"opening_m": 0.05 - 0.005 * i, "moving": i % 2 == 1})
        rec.write_command("jig", "move", x_mm=1.0 * i)
        rec.write_perception("camera_left/fingervision", {"force_px": [0.1 * i, 0.0, 0.2], "marker_count": 3,
                                                         "markers_px": [[4.0, 4.0], [16.0, 8.0], [24.0, 16.0]]})
