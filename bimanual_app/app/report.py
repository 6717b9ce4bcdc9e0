"""``report.html``: one self-contained page (every picture and animation embedded) of a pipeline run."""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

from bimanual_app.io_utils import atomic_open

from .pipeline import StageRecord

_MIME = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".mp4": "video/mp4"}

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0} td,th{border:1px solid #ddd;padding:.25em .6em;text-align:left;font-size:.92em}
th{background:#f5f5f5} .ok{color:#176b2c;font-weight:600} .fail{color:#b00020;font-weight:600} .cached{color:#666}
.warn{background:#fff7e0;border-left:4px solid #f0a000;padding:.4em .8em;margin:.4em 0}
figure{display:inline-block;margin:.5em;vertical-align:top} figure img,figure video{max-width:560px;border:1px solid #ccc}
figcaption{font-size:.85em;color:#555} pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.8em;max-height:18em}
"""


def _embed(path: Path, caption: str) -> str:
    mime = _MIME.get(path.suffix.lower())
    if mime is None or not path.exists():
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    cap = html.escape(caption)
    if mime.startswith("video"):
        body = f'<video controls loop autoplay muted src="data:{mime};base64,{data}"></video>'
    else:
        body = f'<img alt="{cap}" src="data:{mime};base64,{data}">'
    return f"<figure>{body}<figcaption>{cap}</figcaption></figure>"


def _fmt(v, unit: str = "", digits: int = 3) -> str:
    if isinstance(v, float) and math.isinf(v) and v > 0:  # a sigma the views do not determine
        return "unbounded"
    if isinstance(v, (int, float)) and math.isfinite(v):
        return f"{v:.{digits}f}{unit}"
    return html.escape(str(v))


def _json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _evaluation(cal: dict, scene) -> str:
    """The calibration against the scene's ground_truth.yaml (as `bijcr calibrate` prints it), or a note
    that the scene has none."""
    gt = getattr(scene, "ground_truth", None)
    if gt is None:
        return "<p>Ground truth: absent (a real capture): no evaluation.</p>"
    import numpy as np

    from calibration._evaluate import calibration_errors

    try:
        e = calibration_errors(*(np.array(cal[k], dtype=np.float64) for k in ("T_e1_c1", "T_e2_c2")),
                               float(cal["scale"]), np.array(cal["T_b1_b2"], dtype=np.float64), gt)
    except (KeyError, TypeError, ValueError) as err:
        return f"<p>Ground truth present, but the calibration cannot be compared with it ({html.escape(str(err))}).</p>"
    rows = "".join(f"<tr><td>{k}</td><td>{e[k][0]:.3f}°</td><td>{e[k][1]:.2f} mm</td></tr>"
                   for k in ("T_e1_c1", "T_e2_c2", "T_b1_b2"))
    rec = getattr(scene, "reconstruction", None)
    if e["scale_percent"] is not None and getattr(rec, "model", "synthetic") == "synthetic":
        rows += f"<tr><td>scale</td><td colspan=2>{e['scale_percent']:.3f} %</td></tr>"
    return ("<p><b>Against ground_truth.yaml</b> (evaluation only; the solver never reads it):</p>"
            "<table><tr><th>output</th><th>rotation error</th><th>translation error</th></tr>" + rows + "</table>")


def _calibration_section(d: Path, scene=None) -> str:
    cal = _json(d / "calibration.json")
    if cal is None:
        return "<p>No calibration was produced.</p>"
    import numpy as np

    from bimanual_app.transforms import rotation_angle

    unc = cal.get("uncertainty", {}) or {}
    rows = []

    def unc_of(key):
        u = unc.get(key)
        if isinstance(u, dict):
            parts = []
            if "rotation_deg" in u:
                parts.append(f"±{_fmt(u['rotation_deg'], '°', 2)}")
            t = u.get("translation_norm_mm", u.get("translation_mm"))
            if t is not None:
                parts.append(f"±{_fmt(t, ' mm', 1)}")
            if "percent" in u:
                parts.append(f"±{_fmt(u['percent'], ' %', 2)}")
            return " ".join(parts) or html.escape(json.dumps(u))
        if isinstance(u, (int, float)):
            return f"±{_fmt(u, '', 4)}"
        return "–"

    for key in ("T_e1_c1", "T_e2_c2", "T_b1_b2"):
        T = np.array(cal[key])
        t = T[:3, 3] * 1000
        ang = np.degrees(rotation_angle(T[:3, :3]))
        rows.append(f"<tr><td>{key}</td><td>[{t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}] mm</td><td>{ang:.2f}°</td><td>{unc_of(key)}</td></tr>")
    rows.append(f"<tr><td>scale</td><td colspan=2>{_fmt(cal['scale'], '', 5)} m per model unit</td><td>{unc_of('scale')}</td></tr>")
    res = cal.get("residuals", {})
    views = cal.get("views_used", {})
    out = ["<table><tr><th>output</th><th>translation</th><th>rotation angle</th><th>uncertainty (1σ)</th></tr>", *rows, "</table>"]
    out.append(f"<p>Views used: primary {views.get('primary')}, secondary {views.get('secondary')}. "
               f"Mean AX=XB residuals: {_fmt(res.get('rotation_rad', float('nan')) * 180 / math.pi, '°', 3)}, "
               f"{_fmt(res.get('translation_m', float('nan')) * 1000, ' mm', 2)}. Method: {html.escape(str(cal.get('method', '?')))}.</p>")
    for w in cal.get("warnings", []) or []:
        out.append(f'<div class="warn">{html.escape(str(w))}</div>')
    out.append(_evaluation(cal, scene))
    out.append(_embed(d / "calibration.png", "Both arms' end effectors and calibrated cameras in b1, and the metric cloud"))
    pm = (cal.get("info") or {}).get("point_maps") if isinstance(cal.get("info"), dict) else None
    if isinstance(pm, dict):
        what = "Joint estimate (kinematic loop + point maps)" if pm.get("estimator") else "Point-map refinement"
        if pm.get("accepted"):
            out.append(f"<p>{what} applied: overlapping views {_fmt(pm.get('median_before_mm', float('nan')), ' mm', 2)}"
                       f" &rarr; {_fmt(pm.get('median_after_mm', float('nan')), ' mm', 2)} apart (median); the cloud is placed"
                       " by the kinematics.</p>")
        else:
            out.append(f"<p>{what} not applied, the pose-only values are kept: {html.escape(str(pm.get('reason', '')))}.</p>")
        nz, ho = pm.get("noise") or {}, pm.get("held_out_cost") or {}
        if nz and ho:
            out.append(f"<p>Noise from the data: kinematic loop {_fmt(nz.get('loop_rotation_deg', float('nan')), ' deg', 2)} / "
                       f"{_fmt(nz.get('loop_position_mm', float('nan')), ' mm', 1)} per view, point maps "
                       f"{_fmt(nz.get('map_mm_median', float('nan')), ' mm', 2)}; held-out cost (views left out in turn) "
                       f"{_fmt(ho.get('joint', float('nan')), '', 0)} for the joint estimate against "
                       f"{_fmt(ho.get('pose_only', float('nan')), '', 0)} for the pose-only solve.</p>")
        if (d / "point_maps.png").exists():
            out.append(_embed(d / "point_maps.png", "Distances between overlapping views before and after the point-map refinement"))
    return "\n".join(out)


def _segments_section(d: Path, scene=None) -> str:
    seg = _json(d / "segments.json")
    out = []
    if seg is not None:
        objs = seg.get("objects", seg if isinstance(seg, list) else [])
        if objs:
            out.append("<table><tr><th>object</th><th>points</th><th>centroid in b1 (m)</th><th>box extents (cm)</th></tr>")
            for o in objs:
                c = o.get("centroid", [float("nan")] * 3)
                e = (o.get("obb") or {}).get("extents") or [float("nan")] * 3  # segments.json: obb.extents
                out.append(f"<tr><td>{o.get('id')}</td><td>{o.get('points', o.get('n_points', ''))}</td>"
                           f"<td>{', '.join(_fmt(x, '', 3) for x in c)}</td><td>{' x '.join(_fmt(100 * x, '', 1) for x in e)}</td></tr>")
            out.append("</table>")
    out.append(_embed(d / "segments.png", "Segments from above and from the side"))
    if seg is None and not (d / "segments.png").exists():
        return "<p>No segmentation was produced.</p>"
    if scene is not None:
        from .stages import scene_has_masks

        out.append("<p>Per-image masks: " + ("used as extra evidence.</p>" if scene_has_masks(scene.path) else
                                            "absent in the scene: segmented from the cloud alone.</p>"))
    return "\n".join(out)


def _grasps_section(d: Path) -> str:
    g = _json(d / "grasps.json")
    out = []
    if g is not None:
        objs = g.get("objects", [])
        out.append("<table><tr><th>object</th><th>mode</th><th>single-arm grasps (best score)</th>"
                   "<th>two-arm pairs (best score)</th><th>hand-over (score)</th><th>note</th></tr>")

        def count(items) -> str:
            items = [x for x in (items or []) if isinstance(x, dict)]
            if not items:
                return "none"
            return f"{len(items)} ({_fmt(max(float(x.get('score', 0.0)) for x in items), '', 2)})"

        for o in objs:  # grasps.json (docs/grasping.md): grasps, joint_grasps, handover (a dict or null)
            h = o.get("handover")
            ho = f"yes ({_fmt(float(h.get('score', 0.0)), '', 2)})" if isinstance(h, dict) and h else "no"
            if isinstance(h, dict) and (h.get("giver") or {}).get("arm", "primary") != "primary":
                ho += f", the {h['giver']['arm']} gives"
            notes = [str(n) for n in (o.get("notes") or [])]
            for p in o.get("problems") or []:  # "FILE [object K]: message -> fix: ..." -> the message
                p = str(p.get("message", p)) if isinstance(p, dict) else str(p)
                notes.append(p.split("]: ", 1)[-1].split(" -> fix", 1)[0])
            out.append(f"<tr><td>{o.get('id')}</td><td>{html.escape(str(o.get('mode', '')))}</td>"
                       f"<td>{count(o.get('grasps'))}</td><td>{count(o.get('joint_grasps'))}</td><td>{ho}</td>"
                       f"<td>{html.escape(notes[0]) if notes else ''}</td></tr>")
        out.append("</table>")
    out.append(_embed(d / "grasps.png", "Best grasps drawn on the cloud"))
    return "\n".join(out) or "<p>No grasps were produced.</p>"


def _candidate_used(t: dict) -> str:
    """Which grasps.json entry the task's plan used, saying so when it is not the object's first one (the
    grasps table shows the first)."""
    c = ((t.get("plan") or {}).get("info") or {}).get("candidate")
    if not isinstance(c, dict) or not c.get("grasps_json"):
        return ""
    src, score = str(c["grasps_json"]), _fmt(c.get("score"), "", 2)
    first = src.endswith("].handover") or src.endswith(".joint_grasps[0]")
    note = "" if first else (" – an alternative: the grasps table above shows the object's first candidate, "
                             "which the task did not use (its plan or preview failed, or an alternative ranks first)")
    return f"<p>Grasps used: <code>{html.escape(src)}</code> (score {score}){html.escape(note)}.</p>"


def _previews_tried(t: dict) -> str:
    """Every physics preview the task ran, in order, with its verdict and reason (failed ones included)."""
    tried = [p for p in (t.get("previews_tried") or []) if isinstance(p, dict)]
    if len(tried) < 2 and all(p.get("success") for p in tried):
        return ""
    rows = "".join(f"<tr><td>{k + 1}</td><td>{html.escape(str(p.get('object')))}</td>"
                   f"<td>{html.escape(str(p.get('candidate_rank')))}</td>"
                   f'<td class="{"ok" if p.get("success") else "fail"}">{"passed" if p.get("success") else "failed"}'
                   f"</td><td>{html.escape(str(p.get('reason', '')))}</td></tr>" for k, p in enumerate(tried))
    return ("<p>Physics previews tried (a failed one moves on to the next candidate):</p><table><tr><th>#</th>"
            "<th>object</th><th>candidate</th><th>preview</th><th>reason</th></tr>" + rows + "</table>")


def _truth_preview(t: dict, scene) -> str:
    """The same plan in the ground-truth world (task.json ``preview_truth``), or why there is none."""
    pt = t.get("preview_truth")
    if isinstance(pt, dict):
        ok = bool(pt.get("success"))
        return (f'<p>The same plan against the ground truth (evaluation only): <span class="{"ok" if ok else "fail"}">'
                f'{"success" if ok else "failure"}</span> – {html.escape(str(pt.get("reason", "")))}</p>')
    if scene is not None and getattr(scene, "ground_truth", None) is None:
        return "<p>Ground truth: absent: the plan is judged on the reconstruction only.</p>"
    return ""


def _task_section(d: Path, name: str, scene=None) -> str:
    t = _json(d / "task.json")
    out = []
    if t is not None:
        ok = t.get("success")
        cls = "ok" if ok else "fail"
        out.append(f'<p>Outcome: <span class="{cls}">{"success" if ok else "failure"}</span>'
                   f" – {html.escape(str(t.get('reason', t.get('message', ''))))}</p>")
        if t.get("object") is not None:
            why = str(t.get("object_reason", ""))
            out.append(f"<p>Object {html.escape(str(t.get('object')))}" + (f": {html.escape(why)}" if why else "")
                       + "</p>")
        out += [_candidate_used(t), _previews_tried(t), _truth_preview(t, scene)]
    for f in sorted(d.glob("*.gif")) + sorted(d.glob("*.mp4")):
        out.append(_embed(f, f"{name}: physics preview ({f.name})"))
    for f in sorted(d.glob("*.png")):
        out.append(_embed(f, f"{name}: {f.stem.replace('_', ' ')}"))
    return "\n".join(out) or f"<p>No {name} result.</p>"


def write_report(out_dir: Path, scene_name: str, records: list[StageRecord], warnings: list[str],
                 scene=None) -> Path:
    """Write ``out_dir/report.html`` (atomic) and return its path. ``scene``: the loaded Scene, for the
    ground-truth evaluation and the notes on what it lacks (masks, ground truth)."""
    secs = []
    status_rows = []
    total = 0.0
    for r in records:
        cls = {"ran": "ok", "cached": "cached", "failed": "fail", "skipped": "cached"}[r.status]
        total += r.seconds if r.status == "ran" else 0.0
        status_rows.append(f'<tr><td>{html.escape(r.name)}</td><td class="{cls}">{r.status}</td>'
                           f"<td>{r.seconds:.1f} s</td><td>{html.escape(r.message)}</td></tr>")
    secs.append("<h2>Stages</h2><table><tr><th>stage</th><th>status</th><th>time</th><th>note</th></tr>"
                + "".join(status_rows) + f"</table><p>Total time of the stages run now: {total:.1f} s.</p>")
    if warnings:
        secs.append("<h2>Warnings</h2>" + "".join(f'<div class="warn">{html.escape(w)}</div>' for w in warnings))
    if (p := out_dir / "scene_preview.png").exists():
        secs.append("<h2>Capture</h2>" + _embed(p, "The capture: rendered or recorded views of both arms"))
    secs.append("<h2>Calibration</h2>" + _calibration_section(out_dir / "calibration", scene))
    secs.append("<h2>Metric scene and segments</h2>" + _segments_section(out_dir / "segments", scene))
    secs.append("<h2>Grasps</h2>" + _grasps_section(out_dir / "grasps"))
    for task in ("joint-grasp", "handover"):
        d = out_dir / "tasks" / task
        if d.exists():
            secs.append(f"<h2>Task: {task}</h2>" + _task_section(d, task, scene))
    for r in (r for r in records if r.status == "failed"):
        secs.append(f"<h2>Log of the failed stage '{html.escape(r.name)}'</h2><p>{html.escape(r.message)}</p>"
                    f"<pre>{html.escape(r.log[-4000:])}</pre>")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>Bi-JCR report – {html.escape(scene_name)}</title>"
            f"<style>{_CSS}</style></head><body><h1>Bi-JCR report</h1><p>Scene <b>{html.escape(scene_name)}</b>, "
            f"output folder <code>{html.escape(str(out_dir))}</code>. To turn the scene around in 3D (cloud, arms, "
            f"cameras, grasps, task replays): <code>bijcr view {html.escape(str(out_dir))}</code> (docs/viewer.md).</p>"
            + "\n".join(secs) + "</body></html>")
    path = out_dir / "report.html"
    with atomic_open(path) as f:
        f.write(page)
    return path
