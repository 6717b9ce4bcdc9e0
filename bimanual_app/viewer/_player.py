"""Task replay: a task dropdown, a timeline slider, play/pause and the phase, driving both arms, the
moving frames e1, c1, e2, c2 and the carried object (its segment's points moving with the holder)."""

from __future__ import annotations

import threading

import numpy as np

from ._draw import segment_colors, wxyz_xyz
from ._motion import gripper_poses, object_pose, object_track
from ._types import RunLayers, TaskReplay

__all__ = ["TaskPlayer", "START"]

START = "start configuration"


class TaskPlayer:
    """Owns the arms' pose: the start configuration, or the chosen task's plan at the slider's time."""

    def __init__(self, server, layers: RunLayers, arms: dict, frames: dict, q_start: dict, on_object=None):
        self.server, self.layers, self.arms, self.frames, self.q_start = server, layers, arms, frames, q_start
        self.on_object = on_object or (lambda oid: None)  # told which static segment the replay moves
        self.tasks = {t.name: t for t in layers.tasks}
        self.lock = threading.Lock()
        self.task: TaskReplay | None = None
        self.track: list = []
        self.playing = False
        self.labels: dict = {}
        self.objects = {name: self._object_node(t) for name, t in self.tasks.items()}
        gui = server.gui
        with gui.add_folder("Task replay"):
            self.choice = gui.add_dropdown("task", [START, *self.tasks], initial_value=START)
            self.slider = gui.add_slider("time (s)", min=0.0, max=1.0, step=0.01, initial_value=0.0, disabled=True)
            self.button = gui.add_button("Play", disabled=True)
            self.speed = gui.add_slider("speed", min=0.25, max=2.0, step=0.25, initial_value=1.0)
            self.phase_md = gui.add_markdown(self._phase_text(0.0))
        self.choice.on_update(lambda _: self.select(self.choice.value))
        self.slider.on_update(lambda _: self.show(self.slider.value))
        self.button.on_click(lambda _: self.toggle())
        self.select(START)

    def _object_node(self, task: TaskReplay):
        """The task's object (its segment's points) under a frame that the replay moves; hidden until chosen."""
        cloud = self.layers.cloud
        if task.object_id is None or cloud is None or cloud.labels is None:
            return None
        m = cloud.labels == task.object_id
        if not m.any():
            return None
        P = cloud.points[m].astype(np.float32)
        node = self.server.scene.add_frame(f"/tasks/{task.name}/object", show_axes=False, visible=False)
        self.server.scene.add_point_cloud(f"/tasks/{task.name}/object/points", P, segment_colors(cloud.labels[m]),
                                          point_size=0.004, precision="float32", point_shape="circle")
        top = P.mean(axis=0)
        top[2] = P[:, 2].max() + 0.08
        self.labels[task.name] = self.server.scene.add_label(f"/tasks/{task.name}/object/phase", "", position=top,
                                                 anchor="bottom-center")
        return node

    def _pose_fn(self, arm: str, t: float) -> np.ndarray:
        q, _ = self.task.trajectories[arm].sample(t)
        return gripper_poses(self.arms[arm].robot, self.layers.T_b1_base(arm), q)

    def select(self, name: str) -> None:
        with self.lock:
            self.playing = False
            self.task = self.tasks.get(name)
            for n, node in self.objects.items():
                if node is not None:
                    node.visible = n == name
            self.track = object_track(self.task.phases, self._pose_fn) if self.task else []
            has = self.task is not None
            self.slider.max = round(self.task.duration, 2) if has else 1.0
            self.slider.disabled = self.button.disabled = not has
            self.button.label = "Play"
        self.on_object(self.task.object_id if self.task and self.objects.get(name) is not None else None)
        self.slider.value = 0.0
        self.show(0.0)

    def _phase_text(self, t: float) -> str:
        if self.task is None:
            return "Arms at their start configuration (the rest pose the tasks plan from)."
        ph = self.task.phase_at(t)
        verdict = "preview passed" if self.task.success else f"preview failed: {self.task.reason}"
        where = f"**{ph.name}** ({', '.join(ph.arms)}): {ph.note}" if ph else "-"
        return f"`{self.task.name}`, {verdict}  \nt = {t:.2f} / {self.task.duration:.2f} s, phase {where}"

    def show(self, t: float) -> None:
        """Pose everything at time ``t`` of the chosen task (or the start configuration)."""
        with self.lock:
            for arm, view in self.arms.items():
                if self.task is None:
                    q, w = self.q_start[arm], None
                else:
                    q, w = self.task.trajectories[arm].sample(t)
                T_e, _ = view.set(q, w)
                m = 1 if arm == "primary" else 2
                T_c = T_e @ self.layers.T_e_c[arm]
                for key, T in ((f"e{m}", T_e), (f"c{m}", T_c)):
                    if key in self.frames:
                        self.frames[key].wxyz, self.frames[key].position = wxyz_xyz(T)
            node = self.objects.get(self.task.name) if self.task else None
            if node is not None:
                node.wxyz, node.position = wxyz_xyz(object_pose(self.track, self._pose_fn, t))
                ph = self.task.phase_at(t)
                self.labels[self.task.name].text = ph.name if ph else ""
            self.phase_md.content = self._phase_text(t)

    def toggle(self) -> None:
        self.playing = not self.playing and self.task is not None
        self.button.label = "Pause" if self.playing else "Play"

    def tick(self, dt: float) -> None:
        """Advance the replay by ``dt`` seconds of wall time while playing (looping at the end)."""
        if not self.playing or self.task is None:
            return
        t = self.slider.value + dt * self.speed.value
        if t > self.task.duration:
            t = 0.0
        self.slider.value = round(t, 2)  # its on_update poses the scene
