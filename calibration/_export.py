"""Files a calibration is delivered as (all written atomically: temp name, then rename).

- ``calibration.json`` (contract keys + extras), ``scene_b1.ply`` (binary, colours when known);
- ROS: ``ros/static_transforms.yaml`` (parent/child/translation/quaternion list),
  ``ros/static_transforms.launch.xml`` (ROS 2 launch: tf2_ros static_transform_publisher nodes),
  ``ros/static_transforms.launch`` (ROS 1), ``ros/bijcr_calibration.urdf`` (fixed joints, a fragment to
  merge into the cell's URDF).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bimanual_app.transforms import check_shape, xyz_quat_from_T

from ._files import atomic_file, write_json, write_text


def write_calibration_json(path: Path, result, scene_name: str, extra: dict | None = None) -> None:
    """``calibration.json``: the contract keys plus uncertainty, per-arm views, method, warnings."""
    data = result.to_json(scene_name)
    if extra:
        data.update(extra)
    write_json(path, data)


def write_ply(path: Path, points: np.ndarray, colors: np.ndarray | None, unsure: np.ndarray | None = None) -> None:
    """Binary little-endian PLY of points (K, 3) (stored float32, metres) and optional colours (K, 3) uint8;
    with ``unsure`` (K,) bool, a vertex property ``unsure`` (uchar 0 / 1: a point its own map marked unsure
    that other views confirmed; readers that do not know it skip it, ``segmentation.read_unsure`` reads it).

    Written with numpy rather than Open3D: ``import open3d`` pulls in its Plotly/Dash/IPython visualisation
    stack (about 1.2 s, measured), which alone is 40% of the 3-s budget of ``bijcr calibrate``; the format
    is 10 lines. The tests read the file back with Open3D.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    props = ["property float x", "property float y", "property float z"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    if unsure is not None:
        fields.append(("unsure", "u1"))
        props.append("property uchar unsure")
    rec = np.empty(n, dtype=fields)
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    if colors is not None:
        colors = np.asarray(colors, dtype=np.uint8)
        rec["red"], rec["green"], rec["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    if unsure is not None:
        rec["unsure"] = check_shape("unsure", np.asarray(unsure, dtype=bool), (n,))
    header = "\n".join(["ply", "format binary_little_endian 1.0", "comment Bi-JCR metric cloud in frame b1 (metres)",
                        f"element vertex {n}", *props, "end_header"]) + "\n"
    with atomic_file(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(rec.tobytes())


def default_frames(ee_link: str | None = None) -> dict:
    """ROS frame names for b1, b2, e1, e2, c1, c2 (cameras are optical frames: x right, y down, z forward)."""
    ee = ee_link or "ee_link"
    return {"b1": "primary_base_link", "b2": "secondary_base_link", "e1": f"primary_{ee}", "e2": f"secondary_{ee}",
            "c1": "primary_camera_optical_frame", "c2": "secondary_camera_optical_frame"}


def _links(result, frames: dict) -> list[tuple[str, str, np.ndarray, str]]:
    u = result.uncertainty or {}

    def note(key):
        b = u.get(key)
        return "" if not b else f"1-sigma: {b['rotation_deg']:.3f} deg, {b['translation_norm_mm']:.2f} mm"

    return [(frames["b1"], frames["b2"], result.T_b1_b2, note("T_b1_b2")),
            (frames["e1"], frames["c1"], result.T_e1_c1, note("T_e1_c1")),
            (frames["e2"], frames["c2"], result.T_e2_c2, note("T_e2_c2"))]


def _f(v: float) -> str:
    return f"{float(v):.9g}"


def write_ros(out_dir: Path, result, scene_name: str, frames: dict | None = None) -> list[Path]:
    """ROS exports of the camera mounts and the second base; returns the paths written."""
    frames = frames or default_frames()
    out_dir = Path(out_dir)
    links = _links(result, frames)
    head = f"Bi-JCR calibration of scene '{scene_name}' (method {result.method}); metres, quaternion x y z w"
    # YAML
    lines = [f"# {head}", "# each entry: the pose of 'child' in 'parent' (p_parent = T * p_child)", "transforms:"]
    for parent, child, T, note in links:
        xyz, q = xyz_quat_from_T(T)
        lines += [f"  - parent: {parent}", f"    child: {child}",
                  f"    translation: {{x: {_f(xyz[0])}, y: {_f(xyz[1])}, z: {_f(xyz[2])}}}",
                  f"    rotation: {{x: {_f(q[0])}, y: {_f(q[1])}, z: {_f(q[2])}, w: {_f(q[3])}}}"]
        if note:
            lines.append(f"    uncertainty: \"{note}\"")
    lines.append(f"scale: {_f(result.scale)}  # metric = scale * reconstruction units")
    paths = []
    p = out_dir / "ros" / "static_transforms.yaml"
    write_text(p, "\n".join(lines) + "\n")
    paths.append(p)
    # ROS 2 launch (XML)
    x2 = ['<?xml version="1.0"?>', f"<!-- {head} -->", "<launch>"]
    x1 = ['<?xml version="1.0"?>', f"<!-- {head} -->", "<launch>"]
    for parent, child, T, note in links:
        xyz, q = xyz_quat_from_T(T)
        name = f"bijcr_{child}"
        if note:
            x2.append(f"  <!-- {parent} -> {child}: {note} -->")
            x1.append(f"  <!-- {parent} -> {child}: {note} -->")
        x2.append(f'  <node pkg="tf2_ros" exec="static_transform_publisher" name="{name}" args="'
                  f'--x {_f(xyz[0])} --y {_f(xyz[1])} --z {_f(xyz[2])} --qx {_f(q[0])} --qy {_f(q[1])} '
                  f'--qz {_f(q[2])} --qw {_f(q[3])} --frame-id {parent} --child-frame-id {child}"/>')
        x1.append(f'  <node pkg="tf2_ros" type="static_transform_publisher" name="{name}" args="'
                  f'{_f(xyz[0])} {_f(xyz[1])} {_f(xyz[2])} {_f(q[0])} {_f(q[1])} {_f(q[2])} {_f(q[3])} {parent} {child}"/>')
    x2.append("</launch>")
    x1.append("</launch>")
    for name, text in (("static_transforms.launch.xml", x2), ("static_transforms.launch", x1)):
        p = out_dir / "ros" / name
        write_text(p, "\n".join(text) + "\n")
        paths.append(p)
    # URDF fragment
    u = ['<?xml version="1.0"?>', f"<!-- {head} -->",
         "<!-- Fixed joints for the camera mounts and the second base. Standalone-valid; when merging into the",
         "     cell's URDF keep the <joint> and camera <link> elements and rename the links to yours.",
         "     Cameras are optical frames (x right, y down, z forward). rpy: fixed-axis roll, pitch, yaw. -->",
         '<robot name="bijcr_calibration">']
    for link in dict.fromkeys(frames[k] for k in ("b1", "b2", "e1", "e2", "c1", "c2")):
        u.append(f'  <link name="{link}"/>')
    for parent, child, T, note in links:
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # extrinsic x-y-z = URDF roll, pitch, yaw
        if note:
            u.append(f"  <!-- {note} -->")
        u += [f'  <joint name="{parent}_to_{child}" type="fixed">', f'    <parent link="{parent}"/>',
              f'    <child link="{child}"/>',
              f'    <origin xyz="{" ".join(_f(v) for v in T[:3, 3])}" rpy="{" ".join(_f(v) for v in rpy)}"/>',
              "  </joint>"]
    u.append("</robot>")
    p = out_dir / "ros" / "bijcr_calibration.urdf"
    write_text(p, "\n".join(u) + "\n")
    paths.append(p)
    return paths
