"""The replay page around the meshcat scene: the readout, the event timeline, the fitted view.

:func:`page` wraps the meshcat commands of a replay (recorded by
:mod:`pcmm.replay`, handled in order when the page loads) in one
self-contained HTML page: meshcat's viewer script, the commands, and under
the view a bar with the simulated time, each run's configuration and last
event, and a timeline with one marker per event that seeks to the event's
own frame on click (``page.html#t=<seconds>`` opens paused there).  The
page's data (``<script id="pcmm-data">``, JSON) holds the runs' segments
and events, the fitted view and the impulse arrows' scale.
"""
from __future__ import annotations

import base64
import html as _html
import importlib.util
import json
from pathlib import Path

import numpy as np

from .marks import RecordedRun, event_kind
from .sketch import macro_groups, plate_text

#: One colour per overlaid run (``pcmm replay a.npz b.npz``).
RUN_COLOURS = ((0.85, 0.33, 0.10), (0.12, 0.40, 0.85), (0.17, 0.63, 0.17), (0.58, 0.40, 0.74))
#: Timeline colours of the event kinds.
EVENT_COLOURS = {"impact": "#d62728", "merge": "#7b3fb5", "release": "#1a9a3a", "switch": "#666666"}


def _hex(rgb) -> str:
    r, g, b = (int(round(255 * min(max(c, 0.0), 1.0))) for c in rgb[:3])
    return f"#{(r << 16) | (g << 8) | b:06x}"


# ---- events ------------------------------------------------------------------------------
def impulse_label(ev: dict) -> str:
    return f"P = {abs(float(ev['impulse']['normal'])):.4g} N·s"


def drawn_impacts(traj: RecordedRun | list[dict]) -> list[dict]:
    """Events (of a run, or a list of its events) with an impulse to draw (an impact with a
    contact point and a non-zero impulse)."""
    events = traj if isinstance(traj, list) else traj.events
    return [e for e in events if e.get("impact") and e.get("contact_point") is not None
            and e.get("impulse") and float(np.linalg.norm(e["impulse"]["vector"])) > 0]


def describe_event(ev: dict) -> str:
    """What the readout says of an event: what it was (its plate's words), its transition, when."""
    text = f"{plate_text(ev)}: '{ev.get('name', '')}' at t = {float(ev['t']):.7g} s"
    if ev.get("from") != ev.get("to"):
        text += f", {ev.get('from')} → {ev.get('to')}"
    if ev.get("impact") and ev.get("impulse"):
        text += f", {impulse_label(ev)}"
    return text


# ---- the page ------------------------------------------------------------------------------
BAR_PX = 110  # height of the readout + timeline under the view

_CSS = """
body { margin: 0; font: 13px/1.35 system-ui, sans-serif; color: #111; background: #fff; }
#meshcat-pane { width: 100vw; height: calc(100vh - %(bar)dpx); overflow: hidden; }
#pcmm-bar { position: fixed; left: 0; right: 0; bottom: 0; height: %(bar)dpx; box-sizing: border-box;
  padding: 4px 14px; background: #f6f6f6; border-top: 1px solid #bbb; }
#pcmm-bar { min-height: %(bar)dpx; height: auto !important; }
#pcmm-readout { white-space: normal; overflow-wrap: anywhere; }
.pcmm-run-row { white-space: normal; overflow-wrap: anywhere; }
.pcmm-band { position: absolute; top: 0; height: 16px; background: rgba(214, 39, 40, 0.18);
  border: 1px solid rgba(214, 39, 40, 0.6); box-sizing: border-box; font-size: 10px; line-height: 14px;
  color: #8b0000; text-align: center; pointer-events: none; overflow: visible; white-space: nowrap; }
#pcmm-time { font: bold 16px/1.3 ui-monospace, monospace; margin-right: 1.2em; }
.pcmm-config { font-weight: bold; margin-right: 0.6em; }
.pcmm-last { color: #333; margin-right: 1.2em; }
#pcmm-timeline { position: relative; margin-top: 4px; cursor: pointer; }
.pcmm-row { position: relative; height: 16px; border-bottom: 1px solid #c8c8c8; }
.pcmm-row-name { position: absolute; left: 0; top: 0; font-size: 10px; color: #666; pointer-events: none; }
.pcmm-marker { position: absolute; top: 1px; width: 3px; height: 14px; margin-left: -1px; cursor: pointer; }
.pcmm-marker:hover { width: 5px; margin-left: -2px; }
#pcmm-playhead { position: absolute; top: -2px; bottom: -2px; width: 2px; margin-left: -1px; background: #000;
  pointer-events: none; }
#pcmm-angles { font: 11px/1.3 ui-monospace, monospace; color: #333; white-space: nowrap; overflow: hidden; }
#pcmm-legend { margin-top: 3px; font-size: 11px; color: #444; white-space: nowrap; overflow: hidden; }
.pcmm-swatch { display: inline-block; width: 10px; height: 10px; margin: 0 3px 0 10px; vertical-align: -1px; }
"""

_JS = r"""
(function () {
  var D = JSON.parse(document.getElementById("pcmm-data").textContent);
  var A = viewer.animator, TOL = 2e-6, lastBox = null;
  var timeEl = document.getElementById("pcmm-time");
  var head = document.getElementById("pcmm-playhead");
  var anglesEl = document.getElementById("pcmm-angles");
  function keyTimes() {  // the frame times as the animation holds them (float32, from t0)
    var best = null;
    A.actions.forEach(function (a) { a._clip.tracks.forEach(function (tr) {
      if (!best || tr.times.length > best.length) { best = tr.times; } }); });
    return best;
  }
  function snap(c) {  // an event's instant is a frame: land exactly on it
    var k = keyTimes(); if (!k || !k.length) { return c; }
    var lo = 0, hi = k.length - 1;
    while (hi - lo > 1) { var m = (lo + hi) >> 1; if (k[m] <= c) { lo = m; } else { hi = m; } }
    var best = Math.abs(k[lo] - c) <= Math.abs(k[hi] - c) ? k[lo] : k[hi];
    return Math.abs(best - c) <= TOL ? best : c;
  }
  function seek(t) {
    if (!A.actions.length) { return; }
    var c = snap(Math.max(0, t - D.t0));
    A.play(); A.pause(); A.seek(c); A.display_progress(c); viewer.set_dirty(); update();
  }
  function state(run, t) {
    var config = run.segments[0][1], last = null;
    run.segments.forEach(function (s) { if (s[0] <= t + TOL) { config = s[1]; } });
    run.events.forEach(function (e) { if (e.t <= t + TOL) { last = e; } });
    return [config, last];
  }
  function update() {
    var t = D.t0 + (A.time || 0);
    D.runs.forEach(function (run) { run.events.forEach(function (e) { if (Math.abs(e.t - t) <= TOL) { t = e.t; } }); });
    timeEl.textContent = "t = " + t.toFixed(6) + " s";
    D.runs.forEach(function (run, r) {
      var s = state(run, t);
      document.getElementById("pcmm-config-" + r).textContent = (D.runs.length > 1 ? run.name + ": " : "") + s[0];
      document.getElementById("pcmm-last-" + r).textContent = s[1] ? "last event: " + s[1].text : "no event yet";
    });
    head.style.left = (100 * (t - D.t0) / Math.max(D.t1 - D.t0, 1e-300)) + "%";
    var f = D.frames, lo = 0, hi = f.length - 1;  // the frame at or before t
    while (hi > lo) { var m = (lo + hi + 1) >> 1; if (f[m] <= t + TOL) { lo = m; } else { hi = m - 1; } }
    if (D.boxes && lo !== lastBox) { lastBox = lo; viewer.set_3d_pane_size(); }
    anglesEl.textContent = Object.keys(D.angles).length ? "θ (rad): " + Object.keys(D.angles).map(function (k) {
      return k + " " + D.angles[k][lo].toFixed(4); }).join("   ") : "";
  }
  function fit(w, h) {  // the fitted view, centred, at the page's aspect
    if (w === undefined) { w = this.dom_element.offsetWidth; }
    if (h === undefined) { h = this.dom_element.offsetHeight; }
    var c = this.camera;
    if (c.type == "OrthographicCamera") {
      var f = D.view;
      if (D.boxes && lastBox !== null) { var b = D.boxes[lastBox]; f = {left: b[0], right: b[1], bottom: b[2], top: b[3]}; }
      var bw = f.right - f.left, bh = f.top - f.bottom;
      var cx = 0.5 * (f.left + f.right), cy = 0.5 * (f.top + f.bottom);
      if (bw / bh < w / h) { bw = bh * w / h; } else { bh = bw * h / w; }
      c.left = cx - bw / 2; c.right = cx + bw / 2; c.top = cy + bh / 2; c.bottom = cy - bh / 2;
    } else { c.aspect = w / h; }
    c.updateProjectionMatrix(); this.renderer.setSize(w, h); this.set_dirty();
  }
  viewer.set_3d_pane_size = fit;
  var barEl = document.getElementById("pcmm-bar"), paneEl = document.getElementById("meshcat-pane");
  function sizePane() {  // the bar grows with the runs' rows (they wrap, never cut): the view gets the rest
    var h = Math.max(100, window.innerHeight - barEl.offsetHeight);
    if (paneEl.offsetHeight !== h) { paneEl.style.height = h + "px"; viewer.set_3d_pane_size(); }
  }
  sizePane();
  viewer.set_3d_pane_size();
  document.querySelectorAll(".pcmm-marker").forEach(function (m) {
    m.addEventListener("click", function (ev) { ev.stopPropagation(); seek(parseFloat(m.dataset.t)); });
  });
  document.getElementById("pcmm-timeline").addEventListener("click", function (ev) {
    var box = this.getBoundingClientRect();
    seek(D.t0 + (ev.clientX - box.left) / box.width * (D.t1 - D.t0));
  });
  (function loop() { sizePane(); update(); requestAnimationFrame(loop); })();
  var m = (location.hash + "&" + location.search).match(/[#?&]t=([-+0-9.eE]+)/);
  if (m) { seek(parseFloat(m[1])); }
  window.pcmm = { seek: seek, data: D };
})();
"""


def _events_data(run: RecordedRun) -> list[dict]:
    """The timeline's entries of ``run``'s events; an impact with an arrow carries its impulse."""
    events = list(run.events)  # each record built once (an EventLog builds one on every read)
    drawn = {id(e) for e in drawn_impacts(events)}
    return [{"t": float(e["t"]), "kind": event_kind(e), "text": describe_event(e),
             **({"impulse": float(e["impulse"]["normal"]), "label": impulse_label(e)} if id(e) in drawn else {})}
            for e in events]


def page_data(runs, info) -> dict:
    view = info["view"]
    several = len(runs) > 1
    return {
        "t0": info["t0"], "t1": info["t1"], "fps": info["fps"],
        "view": {"left": view.left, "right": view.right, "top": view.top, "bottom": view.bottom},
        "boxes": info.get("boxes"),  # the view per frame (--view follow | configuration), else null
        "layout": info.get("layout", "overlay"),
        "arrow_scale": view.arrow_scale, "bar_length": view.bar_length,
        "frames": [float(t) for t in info["times"]],  # the frame times, s
        "angles": {link: [round(float(a), 6) for a in th] for link, th in info.get("angles", {}).items()},
        "runs": [{"name": run_name(r), "impact": r.impact,
                  "colour": _hex(RUN_COLOURS[i % len(RUN_COLOURS)]) if several else None,
                  "segments": [[float(s.t[0]), s.configuration] for s in r.segments],
                  "groups": macro_groups(r),
                  "events": _events_data(r)}
                 for i, r in enumerate(runs)],
    }


def run_name(traj: RecordedRun) -> str:
    return f"{traj.scene_name}{'' if traj.impact else ' (without impact)'}"


def _bar_html(data) -> str:
    esc = _html.escape
    t0, t1 = data["t0"], data["t1"]
    readout = [f'<span id="pcmm-time">t = {t0:.6f} s</span>']
    several = len(data["runs"]) > 1
    rows = []
    for r, run in enumerate(data["runs"]):
        name = (run["name"] + ": ") if several else ""
        state = (f'<span class="pcmm-config" id="pcmm-config-{r}">{esc(name + run["segments"][0][1])}</span>'
                 f'<span class="pcmm-last" id="pcmm-last-{r}">no event yet</span>')
        if several:  # one row per run, each in full (it wraps, never cut)
            swatch = f'<span class="pcmm-swatch" style="background:{run["colour"]};margin-left:0"></span>'
            readout.append(f'</div><div class="pcmm-run-row" id="pcmm-run-{r}">{swatch}{state}')
        else:
            readout.append(state)
        marks = []
        for group in run.get("groups", []):  # a macro-impact: one band with its count
            if len(group) < 2:
                continue
            a, b = run["events"][group[0]]["t"], run["events"][group[-1]]["t"]
            left = 100.0 * (a - t0) / max(t1 - t0, 1e-300)
            width = max(100.0 * (b - a) / max(t1 - t0, 1e-300), 0.3)
            marks.append(f'<div class="pcmm-band" data-run="{r}" data-count="{len(group)}" data-t0="{a!r}" '
                         f'data-t1="{b!r}" style="left:{left:.5f}%;width:{width:.5f}%" '
                         f'title="macro-impact: {len(group)} impacts">{len(group)}×</div>')
        for i, e in enumerate(run["events"]):
            pct = 100.0 * (e["t"] - t0) / max(t1 - t0, 1e-300)
            marks.append(f'<div class="pcmm-marker pcmm-{e["kind"]}" data-run="{r}" data-event="{i}" '
                         f'data-t="{e["t"]!r}" style="left:{pct:.5f}%;background:{EVENT_COLOURS[e["kind"]]}" '
                         f'title="{esc(e["text"])}"></div>')
        label = esc(run["name"]) if len(data["runs"]) > 1 else ""
        rows.append(f'<div class="pcmm-row" data-run="{r}"><span class="pcmm-row-name">{label}</span>'
                    + "".join(marks) + "</div>")
    legend = "".join(f'<span class="pcmm-swatch" style="background:{c}"></span>{k}' for k, c in EVENT_COLOURS.items())
    if len(data["runs"]) > 1:
        legend += "".join(f'<span class="pcmm-swatch" style="background:{run["colour"]}"></span>{esc(run["name"])}'
                          for run in data["runs"])
    if data["arrow_scale"] > 0:
        legend += (f' &nbsp; arrows: impulse on body b, 1 N·s = {data["arrow_scale"]:.3g} m'
                   f' &nbsp; scale bar {data["bar_length"]:g} m')
    return (f'<div id="pcmm-bar"><div id="pcmm-readout">{"".join(readout)}</div><div id="pcmm-angles"></div>'
            f'<div id="pcmm-timeline">{"".join(rows)}<div id="pcmm-playhead" style="left:0%"></div></div>'
            f'<div id="pcmm-legend">events:{legend}</div></div>')


def _script_json(obj) -> str:
    return json.dumps(obj).replace("</", "<\\/")


def _viewer_js() -> str:
    """meshcat's viewer script (its package's ``viewer/dist/main.min.js``)."""
    path = Path(importlib.util.find_spec("meshcat").origin).parent / "viewer" / "dist" / "main.min.js"
    return path.read_text(encoding="utf-8")


#: How a command names a picture of the page's image table (``pcmm-image:<index>``).
IMAGE_REF = "pcmm-image:"

#: Before meshcat reads a command, a texture's ``pcmm-image:<i>`` becomes PCMM_IMAGES[i] (its data URL).
_RESOLVE_IMAGES = f"""
var PCMM_HANDLE = viewer.handle_command.bind(viewer);
viewer.handle_command = function (cmd) {{
  if (cmd.type === "set_object" && cmd.object && cmd.object.images) {{
    cmd.object.images.forEach(function (im) {{
      if (typeof im.url === "string" && im.url.indexOf("{IMAGE_REF}") === 0) {{
        im.url = PCMM_IMAGES[parseInt(im.url.slice({len(IMAGE_REF)}), 10)];
      }}
    }});
  }}
  PCMM_HANDLE(cmd);
}};
"""


def page(runs, info, commands: list[bytes], images: list[str] = ()) -> str:
    """The page (text) for ``runs``, with ``info`` from the scene builder and its ``commands``;
    ``images`` are the distinct pictures (data URLs) the commands name ``pcmm-image:<index>``."""
    data = page_data(runs, info)
    title = "pcmm replay: " + " vs ".join(run_name(r) for r in runs)
    packed = ",\n".join(f'"{base64.b64encode(c).decode("ascii")}"' for c in commands)
    return f"""<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{_html.escape(title)}</title>
<style>{_CSS % {"bar": BAR_PX}}</style></head>
<body>
<div id="meshcat-pane"></div>
{_bar_html(data)}
<script type="application/json" id="pcmm-data">{_script_json(data)}</script>
<script>{_viewer_js()}</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
/* each distinct picture once (data URLs); the commands name them "{IMAGE_REF}<index>" */
var PCMM_IMAGES = {_script_json(list(images))};
{_RESOLVE_IMAGES}
/* the replay's meshcat commands (msgpack, base64), handled in order */
var PCMM_COMMANDS = [
{packed}
];
PCMM_COMMANDS.forEach(function (b64) {{
  var s = atob(b64), bytes = new Uint8Array(s.length);
  for (var i = 0; i < s.length; i++) {{ bytes[i] = s.charCodeAt(i); }}
  viewer.handle_command_bytearray(bytes);
}});
</script>
<script>{_JS}</script>
</body>
</html>
"""
