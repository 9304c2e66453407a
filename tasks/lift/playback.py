"""The lift stage's review artifact: both fighters' 3D joints as one self-contained HTML page.

The page draws the skeletons on a canvas with its own few lines of JavaScript (no libraries, no
network): drag to turn the view, the slider or space bar to move through time.
"""

from __future__ import annotations

import json

import numpy as np

from tasks.pose.overlay import BONE_INDEX, ROLE_COLOURS

_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>__TITLE__</title>
<style>body{margin:0;font:14px sans-serif;background:#111;color:#ddd}
#bar{padding:6px}canvas{display:block;background:#1b1b1b;cursor:grab}</style></head>
<body><div id="bar"><button id="play">play</button>
<input id="t" type="range" min="0" value="0" style="width:60%"> <span id="label"></span></div>
<canvas id="c" width="960" height="640"></canvas>
<script>
const D = __DATA__;
const c = document.getElementById("c"), g = c.getContext("2d");
const slider = document.getElementById("t"), label = document.getElementById("label");
slider.max = D.frames - 1;
let yaw = 0.6, pitch = 0.35, frame = 0, playing = false, drag = null;
function view(p) {
  const x = p[0] - D.centre[0], y = p[1] - D.centre[1], z = p[2];
  const cx = Math.cos(yaw) * x - Math.sin(yaw) * y, cy = Math.sin(yaw) * x + Math.cos(yaw) * y;
  const sy = Math.cos(pitch) * z - Math.sin(pitch) * cy;
  const s = c.height / (D.extent * 1.6);
  return [c.width / 2 + s * cx, c.height * 0.8 - s * sy];
}
function draw() {
  g.clearRect(0, 0, c.width, c.height);
  g.strokeStyle = "#333"; g.lineWidth = 1;
  const [x0, y0] = D.centre;
  const line = (a, b) => { g.beginPath(); g.moveTo(...view(a)); g.lineTo(...view(b)); g.stroke(); };
  for (let i = -4; i <= 4; i++) {
    line([x0 + i / 2, y0 - 2, 0], [x0 + i / 2, y0 + 2, 0]);
    line([x0 - 2, y0 + i / 2, 0], [x0 + 2, y0 + i / 2, 0]);
  }
  for (const f of D.fighters) {
    const pts = f.joints[frame];
    if (!pts) continue;
    g.strokeStyle = f.colour; g.lineWidth = 3;
    for (const [i, j] of D.bones) {
      if (pts[i] !== null && pts[j] !== null) line(pts[i], pts[j]);
    }
  }
  slider.value = frame;
  label.textContent = `frame ${frame} / ${D.frames - 1} (${(frame / D.fps).toFixed(2)} s)`;
}
c.onmousedown = e => drag = [e.clientX, e.clientY, yaw, pitch];
window.onmouseup = () => drag = null;
window.onmousemove = e => { if (!drag) return;
  yaw = drag[2] + (e.clientX - drag[0]) / 200;
  pitch = Math.max(-1.4, Math.min(1.4, drag[3] + (e.clientY - drag[1]) / 200)); draw(); };
slider.oninput = () => { frame = +slider.value; draw(); };
document.getElementById("play").onclick = () => playing = !playing;
window.onkeydown = e => { if (e.code === "Space") { playing = !playing; e.preventDefault(); } };
setInterval(() => { if (playing) { frame = (frame + 1) % D.frames; draw(); } }, 1000 / D.fps);
draw();
</script></body></html>
"""


def playback_html(fighters: dict[str, np.ndarray], *, fps: float, title: str) -> str:
    """The page for ``fighters``: role -> (T, 33, 3) world joints in metres (NaN where unknown),
    all with the same T. Coordinates are rounded to millimetres to keep the page small."""
    lengths = {len(joints) for joints in fighters.values()}
    if len(lengths) != 1:
        raise ValueError(f"fighters must share one frame count, got {sorted(lengths)}")
    everything = np.concatenate([j.reshape(-1, 3) for j in fighters.values()])
    finite = everything[np.isfinite(everything).all(1)]
    centre = finite.mean(0) if len(finite) else np.zeros(3)
    extent = float(np.ptp(finite, axis=0).max()) if len(finite) else 2.0
    data = {
        "fps": fps,
        "frames": lengths.pop(),
        "centre": [round(float(v), 3) for v in centre],
        "extent": max(extent, 1.0),
        "bones": BONE_INDEX.tolist(),
        "fighters": [
            {
                "role": role,
                "colour": "#{2:02x}{1:02x}{0:02x}".format(*ROLE_COLOURS[role]),
                "joints": [
                    [
                        None if not np.isfinite(p).all() else [round(float(v), 3) for v in p]
                        for p in frame
                    ]
                    for frame in joints
                ],
            }
            for role, joints in fighters.items()
        ],
    }
    return _PAGE.replace("__TITLE__", title).replace("__DATA__", json.dumps(data))
