"""The viewer's server: build every layer of a run in a viser scene, the GUI to toggle them, and serve
until a timeout or Ctrl-C."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ._types import RunLayers

__all__ = ["build_scene", "serve"]

N_SINGLE, N_PAIRS = 3, 3  # grasps drawn per object: the best single-arm grasps and two-arm pairs
GRASP_COLORS = {"single": (40, 110, 230), "pair_primary": (240, 140, 20), "pair_secondary": (150, 60, 200),
                "pick": (30, 170, 70), "transfer": (120, 220, 140), "receiver": (220, 40, 40)}


#: short names of the layers (``bijcr view --hide NAME``) -> their root node
LAYER_ROOTS = {"cloud": "/cloud", "ids": "/labels", "arms": "/arms", "cameras": "/cameras", "frames": "/frames",
               "sigma": "/sigma", "grasps": "/grasps", "carried": "/tasks"}


def _layer_toggles(server, roots: dict[str, str], hidden: tuple = ()) -> dict:
    """One checkbox per present layer, each showing / hiding its root node; the layers whose root is in
    ``hidden`` start hidden."""
    nodes, boxes = {}, {}
    for label, root in roots.items():
        nodes[label] = server.scene.add_frame(root, show_axes=False, visible=root not in hidden)
    with server.gui.add_folder("Layers"):
        for label, root in roots.items():
            box = server.gui.add_checkbox(label, initial_value=root not in hidden)
            box.on_update(lambda _, lb=label, b=box: setattr(nodes[lb], "visible", b.value))
            boxes[label] = box
    return boxes


def _grasp_panel(server, layers: RunLayers, gripper) -> None:
    """The grasps of the object chosen in a dropdown, drawn as gripper meshes under ``/grasps``."""
    from ._draw import draw_gripper, segment_colors

    drawn: list = []

    def show(oid: int) -> None:
        for h in drawn:
            h.remove()
        drawn.clear()
        og = layers.grasps[oid]
        for k, g in enumerate(og.single[:N_SINGLE]):
            drawn.append(draw_gripper(server, f"/grasps/single_{k}", gripper, g, GRASP_COLORS["single"],
                                      opacity=1.0 if k == 0 else 0.45))
        for k, (p, s) in enumerate(og.joint[:N_PAIRS]):
            drawn.append(draw_gripper(server, f"/grasps/pair_{k}_primary", gripper, p, GRASP_COLORS["pair_primary"],
                                      opacity=1.0 if k == 0 else 0.45))
            drawn.append(draw_gripper(server, f"/grasps/pair_{k}_secondary", gripper, s,
                                      GRASP_COLORS["pair_secondary"], opacity=1.0 if k == 0 else 0.45))
        for key, g in (og.handover or {}).items():
            drawn.append(draw_gripper(server, f"/grasps/handover_{key}", gripper, g, GRASP_COLORS[key]))
        cloud = layers.cloud
        if og.T_move is not None and cloud is not None and cloud.labels is not None and (cloud.labels == oid).any():
            P = cloud.points[cloud.labels == oid]
            P = P @ og.T_move[:3, :3].T + og.T_move[:3, 3]  # the object at the transfer pose
            C = (0.5 * segment_colors(cloud.labels[cloud.labels == oid]) + 127).astype(np.uint8)
            drawn.append(server.scene.add_point_cloud("/grasps/handover_object", P.astype(np.float32), C,
                                                      point_size=0.004, precision="float32", point_shape="circle"))

    names = {f"object {oid}": oid for oid in sorted(layers.grasps)}
    with server.gui.add_folder("Grasps"):
        first = next((n for n, oid in names.items() if layers.grasps[oid].handover), next(iter(names)))
        dd = server.gui.add_dropdown("object", list(names), initial_value=first)  # a hand-over shows all kinds
        md = server.gui.add_markdown("")
    legend = ("blue: best single-arm grasps; orange / purple: two-arm pair (primary / secondary); "
              "green: hand-over giver (pick, then at the transfer pose, with the object there); red: receiver")

    def on_change(_=None) -> None:
        oid = names[dd.value]
        show(oid)
        md.content = f"{layers.grasps[oid].summary()}  \n{legend}"

    dd.on_update(on_change)
    on_change()


def build_scene(server, layers: RunLayers, hidden: tuple = ()):
    """Draw every present layer of ``layers`` in ``server`` (``hidden``: root nodes that start hidden);
    returns the task player."""
    from bimanual_app.planning import default_ready
    from bimanual_app.robots import load_robot
    from grasping import load_gripper

    from ._arms import ArmView
    from ._draw import draw_cameras, draw_cloud, draw_frames, draw_sigma
    from ._player import TaskPlayer

    server.scene.set_up_direction("+z")
    server.scene.world_axes.visible = False
    mid = 0.5 * layers.T_b1_b2[:3, 3]
    server.initial_camera.position = tuple(mid + np.array([-0.25, -0.7, 0.8]))
    server.initial_camera.look_at = tuple(mid + np.array([0.0, 0.0, 0.05]))
    roots = {}
    if layers.cloud is not None:
        roots["cloud"] = "/cloud"
        if layers.cloud.labels is not None:
            roots["segment ids"] = "/labels"
    roots["arms"] = "/arms"
    if layers.cameras:
        roots["capture cameras"] = "/cameras"
    roots["frames b1 b2 e c"] = "/frames"
    if layers.sigma_b1_b2_m is not None:
        roots["1-sigma of T_b1_b2"] = "/sigma"
    if layers.grasps:
        roots["grasps"] = "/grasps"
    if layers.tasks:
        roots["carried object"] = "/tasks"
    _layer_toggles(server, roots, hidden)

    cloud_h = draw_cloud(server, layers.cloud) if layers.cloud is not None else {}
    if layers.cameras:
        draw_cameras(server, layers)
    frames = draw_frames(server, layers)
    if layers.sigma_b1_b2_m is not None:
        draw_sigma(server, layers)
    robot = load_robot(layers.robot)
    gripper = load_gripper(layers.robot)
    arms = {a: ArmView(server, robot, gripper, a, layers.T_b1_base(a)) for a in ("primary", "secondary")}
    if layers.grasps:
        _grasp_panel(server, layers, gripper)

    def hide_static(oid) -> None:  # the replay's moving copy of the object replaces the still one
        for k, h in cloud_h.items():
            if isinstance(k, int):
                h.visible = k != oid

    q0 = default_ready(robot)
    player = TaskPlayer(server, layers, arms, frames, {"primary": q0, "secondary": q0}, on_object=hide_static)
    if cloud_h and layers.cloud.labels is not None and layers.cloud.colors is not None:
        seg_box = server.gui.add_checkbox("cloud in segment colours", initial_value=True)

        def recolor(_) -> None:
            for k, (seg, rgb) in cloud_h["_rgb"].items():
                cloud_h[k].colors = seg if seg_box.value else rgb

        seg_box.on_update(recolor)
    if layers.notes:
        with server.gui.add_folder("Not shown", expand_by_default=False):
            server.gui.add_markdown("\n".join(f"- {n}" for n in layers.notes))
    return player


def serve(layers: RunLayers, host: str = "127.0.0.1", port: int = 8080, timeout: float | None = None,
          on_ready: Callable[[int], None] | None = None,
          task: str | None = None, at: float = 0.0, hide: tuple = ()) -> int:
    """Serve ``layers`` until ``timeout`` seconds pass (None: until Ctrl-C), opening with ``task``'s replay
    at ``at`` seconds when given and the layers named in ``hide`` (keys of :data:`LAYER_ROOTS`) hidden.
    Returns the port served on."""
    import contextlib
    import sys

    import viser

    with contextlib.redirect_stdout(sys.stderr):  # viser's own banner: keep stdout for the URL lines
        server = viser.ViserServer(host=host, port=port, label="Bi-JCR viewer", verbose=False)
    try:
        player = build_scene(server, layers, tuple(LAYER_ROOTS[h] for h in hide))
        if task is not None:
            player.choice.value = task
            player.slider.value = min(max(at, 0.0), player.slider.max)
        real_port = server.get_port()
        if on_ready is not None:
            on_ready(real_port)
        t_end = None if timeout is None else time.monotonic() + timeout
        last = time.monotonic()
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.05)
            now = time.monotonic()
            player.tick(now - last)
            last = now
        return real_port
    finally:
        with contextlib.redirect_stdout(sys.stderr):
            server.stop()
