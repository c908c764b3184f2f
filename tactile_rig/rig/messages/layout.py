"""A Foxglove layout that opens a session with a panel for each of its views (``foxglove.layouts``).

Tab "Session": the camera image with the marker annotations over it; the 3-D scene (the frame tree,
the stage under the sensor, the tactile point cloud, the marker arrows) on a 100 mm grid in mm; plots
of the scale's force and the fingertip's force/torque; the gripper's opening; the jig's state over
time; the log. Tab "Bench": the live services (tare the scale, stop motion), the session's parameters
and the raw messages of a perception topic. The file ``docs/foxglove/tactile-rig-layout.json`` is
:func:`session_layout` for the mock bench's camera names; ``tactile-rig export layout`` writes one for
a bench's own cameras.
"""

from __future__ import annotations

import json
from typing import Any, Sequence

__all__ = ["session_layout", "DEFAULT_CAMERAS"]

DEFAULT_CAMERAS = ("camera_fingervision", "camera_gelsight")


def session_layout(cameras: Sequence[str] = DEFAULT_CAMERAS) -> str:
    """The layout (JSON text) for a session of ``cameras`` (the first is shown in the Image panel)."""
    import foxglove.layouts as fl  # foxglove-sdk is the optional extra: imported when a layout is made

    if not cameras:
        raise ValueError("a layout needs at least one camera name (the Image panel shows its frames)")
    cams = [c.strip("/") for c in cameras]
    first = cams[0]
    image = fl.ImagePanel(title=f"{first}: markers over the image", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic=f"/{first}/image/compressed", synchronize=True,
                                      annotations={f"/{first}/markers": fl.ImageAnnotationSettings(visible=True)})))
    topics: dict[str, Any] = {"/tf": fl.BaseRendererBaseSettings(visible=True)}
    for c in cams:
        topics[f"/{c}/height/points"] = fl.BaseRendererPointCloudTopicSettings(
            visible=True, point_size=3.0, color_mode="colormap", color_field="height_mm", color_map="turbo")
        topics[f"/{c}/marker_arrows"] = fl.BaseRendererSceneUpdateTopicSettings(visible=True)
    topics["/jig_accuracy/estimate/pose"] = fl.BaseRendererBaseSettings(visible=True)
    scene = fl.ThreeDeePanel(title="3-D: stage, sensor, point cloud, arrows (mm)", config=fl.ThreeDeeConfig(
        follow_tf="world", camera_state=fl.ThreeDeeCameraState(distance=120.0, perspective=True, phi=50.0,
                                                                near=0.1, far=10000.0),
        layers={"grid": fl.BaseRendererGridLayerSettings(frame_id="world", size=100.0, divisions=20.0,
                                                        line_width=0.5, color="#248eff40")},
        scene=fl.BaseRendererSceneSettings(transforms=fl.BaseRendererTransforms(axis_size=5.0, label_size=2.0)),
        topics=topics))
    forces = fl.PlotPanel(title="force (N)", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value="/scale/force.force_n", id="scale"),
        *[fl.PlotSeries(value=f"/{c}/wrench.force_n.{a}", id=f"{c} {a}") for c in cams for a in "xyz"],
    ], show_legend=True, y_axis_label="N"))
    torque = fl.PlotPanel(title="torque (N·mm)", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value=f"/{c}/wrench.torque_nmm.{a}", id=f"{c} {a}") for c in cams for a in "xyz"],
        show_legend=True, y_axis_label="N·mm"))
    gripper = fl.PlotPanel(title="gripper opening (m)", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value="/gripper/joint_states.joints[0].position", id="opening_m")], y_axis_label="m"))
    state = fl.StateTransitionsPanel(title="jig state", config=fl.StateTransitionsConfig(paths=[
        fl.StateTransitionsSeries(value="/state/jig.state", label="jig")]))
    log = fl.LogPanel(title="log", config=fl.LogConfig(topic_to_render="/log", show_name=True))

    def split(direction: Any, *parts: tuple[float, Any]) -> Any:
        return fl.SplitContainer(direction=direction,
                                 items=[fl.SplitItem(proportion=p, content=c) for p, c in parts])

    session = split("row", (1.0, split("column", (1.0, image), (1.0, scene))),
                    (1.0, split("column", (1.0, forces), (1.0, torque), (0.7, gripper), (0.5, state), (1.0, log))))
    services = split("column",
                     (1.0, fl.ServiceCallPanel(title="tare the scale", config=fl.ServiceCallConfig(
                         service_name="tare_scale", request_payload="{}", button_text="Tare"))),
                     (1.0, fl.ServiceCallPanel(title="stop motion", config=fl.ServiceCallConfig(
                         service_name="stop_motion", request_payload="{}", button_text="Stop", button_color="#d0342c"))),
                     (2.0, fl.ParametersPanel(title="session parameters")))
    bench = split("row", (1.0, services), (2.0, fl.RawMessagesPanel(
        title="perception result", config=fl.RawMessagesConfig(topic_path=f"/perception/{first}/fingervision"))))
    layout = fl.Layout(content=fl.TabContainer(selected_tab_index=0, tabs=[
        fl.TabItem(title="Session", content=session), fl.TabItem(title="Bench", content=bench)]))
    return json.dumps(json.loads(layout.to_json()), indent=1, sort_keys=True) + "\n"
