"""viewer.html: the solved sub-elements as a self-contained WebGL1 page (no external URL), coloured
like the image (core.colour): orbit, zoom, both sides of two-sided elements; it sets `#status`
to "ok N triangles" once drawn. Given a core.smooth.SmoothMesh (`smooth=`), the corners show the
radiance reconstructed at shared vertices; without it, one flat colour per sub-element."""

from __future__ import annotations

import base64
import html
import json
import math
import os

import numpy as np

from radiosity.core.bundles import Camera, Partition
from radiosity.core.colour import auto_exposure, tonemap
from radiosity.core.smooth import SmoothMesh
from radiosity.formats.files import temp_path

#: Above this many triangles the viewer shows every s-th sub-element only (with a warning).
VIEWER_MAX_TRIANGLES = 2_000_000
#: The viewer pushes each vertex this many screen pixels away from its sub-element's centre,
#: which hides the cracks that T-junctions between sub-elements of different depth leave.
VIEWER_GROW_PX = 0.6

_VIEWER = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>%(title)s</title>
<style>
html,body{margin:0;height:100%%;overflow:hidden;background:#1e2227;color:#dde;font:13px sans-serif}
canvas{display:block;width:100%%;height:100%%;cursor:grab;touch-action:none}
#cap{position:absolute;left:8px;top:6px;background:rgba(0,0,0,.5);padding:5px 9px;border-radius:4px;
pointer-events:none;line-height:1.45}
#warn{color:#fc6}
</style></head>
<body><canvas id="view"></canvas>
<div id="cap"><b>%(title)s</b><br>%(caption)s<br><span id="warn">%(warning)s</span>
<span id="help">drag: orbit &middot; wheel: zoom &middot; double-click: reset</span><br>
<span id="status">loading</span><br>%(luxhelp)s</div>
<div id="legend" style="display:none;position:absolute;right:10px;bottom:10px;background:rgba(0,0,0,.5);padding:6px 9px;border-radius:4px;pointer-events:none">
illuminance (lx)<div style="width:220px;height:12px;margin:4px 0;background:linear-gradient(to right,%(ramp)s)"></div>
<span style="float:left">0</span><span style="float:right" id="luxmax">%(luxmax)s</span></div>
<script type="application/octet-stream" id="d-lux">%(lux)s</script>
<script type="application/octet-stream" id="d-pos">%(pos)s</script>
<script type="application/octet-stream" id="d-nv">%(nv)s</script>
<script type="application/octet-stream" id="d-col">%(col)s</script>
<script>
(function () {
"use strict";
var META = %(meta)s;
var status = document.getElementById("status");
function report(s) { status.textContent = s; document.body.setAttribute("data-status", s); }
function bytes(id) {
  var s = atob(document.getElementById(id).textContent.replace(/\s+/g, ""));
  var u = new Uint8Array(s.length);
  for (var i = 0; i < s.length; i++) u[i] = s.charCodeAt(i);
  return u;
}
try {
var canvas = document.getElementById("view");
var gl = canvas.getContext("webgl", {antialias: true, preserveDrawingBuffer: true}) ||
         canvas.getContext("experimental-webgl", {preserveDrawingBuffer: true});
if (!gl) { report("error: WebGL is not available in this browser"); return; }

// sub-elements: 4 float32 vertices, vertex count, 25 bytes: per corner [front rgb, back rgb]
// (sRGB), then two-sided
var pos = new Float32Array(bytes("d-pos").buffer), nv = bytes("d-nv"), col = bytes("d-col");
// lux mode (key L): per sub-element [front rgb, back rgb] false colour of its illuminance
var lux = META.lux ? bytes("d-lux") : null;
var m = nv.length, ntri = 0, i, j, k;
for (i = 0; i < m; i++) ntri += nv[i] - 2;
var P = new Float32Array(ntri * 9), Q = new Float32Array(ntri * 9);
var F = new Uint8Array(ntri * 12), B = new Uint8Array(ntri * 12);
var FL = lux ? new Uint8Array(ntri * 12) : null, BL = lux ? new Uint8Array(ntri * 12) : null;
var t = 0, fan = [0, 1, 2, 0, 2, 3];
for (i = 0; i < m; i++) {
  var cx = 0, cy = 0, cz = 0;  // vertex mean, the point each vertex is pushed away from
  for (k = 0; k < nv[i]; k++) {
    cx += pos[12 * i + 3 * k]; cy += pos[12 * i + 3 * k + 1]; cz += pos[12 * i + 3 * k + 2];
  }
  cx /= nv[i]; cy /= nv[i]; cz /= nv[i];
  for (j = 0; j < nv[i] - 2; j++, t++) {
    for (k = 0; k < 3; k++) {
      var s = 12 * i + 3 * fan[3 * j + k], d = 9 * t + 3 * k, c = 12 * t + 4 * k;
      var q = 25 * i + 6 * fan[3 * j + k];
      P[d] = pos[s]; P[d + 1] = pos[s + 1]; P[d + 2] = pos[s + 2];
      Q[d] = cx; Q[d + 1] = cy; Q[d + 2] = cz;
      F[c] = col[q]; F[c + 1] = col[q + 1]; F[c + 2] = col[q + 2]; F[c + 3] = 255;
      B[c] = col[q + 3]; B[c + 1] = col[q + 4]; B[c + 2] = col[q + 5];
      B[c + 3] = col[25 * i + 24] ? 255 : 0;
      if (lux) {
        FL[c] = lux[6 * i]; FL[c + 1] = lux[6 * i + 1]; FL[c + 2] = lux[6 * i + 2]; FL[c + 3] = 255;
        BL[c] = lux[6 * i + 3]; BL[c + 1] = lux[6 * i + 4]; BL[c + 2] = lux[6 * i + 5];
        BL[c + 3] = B[c + 3];
      }
    }
  }
}

function shader(type, src) {
  var sh = gl.createShader(type);
  gl.shaderSource(sh, src); gl.compileShader(sh);
  if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
  return sh;
}
var prog = gl.createProgram();
gl.attachShader(prog, shader(gl.VERTEX_SHADER,
  "attribute vec3 aPos; attribute vec3 aCen; attribute vec4 aFront; attribute vec4 aBack;" +
  "uniform mat4 uMVP; uniform vec2 uPx; varying vec4 vFront; varying vec4 vBack;" +
  // sRGB bytes to linear: colours are interpolated in linear radiance, as in mesh.glb
  "vec3 lin(vec3 c) {" +
  " return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c)); }" +
  "void main() { vFront = vec4(lin(aFront.rgb), aFront.a); vBack = vec4(lin(aBack.rgb), aBack.a);" +
  // push the vertex GROW_PX pixels away from its element's centre on screen: no T-junction cracks
  " vec4 p = uMVP * vec4(aPos, 1.0); vec4 c = uMVP * vec4(aCen, 1.0);" +
  " if (p.w > 0.0 && c.w > 0.0) { vec2 d = (p.xy / p.w - c.xy / c.w) / uPx; float l = length(d);" +
  " if (l > 1e-6) p.xy += d / l * " + META.grow_px.toFixed(3) + " * uPx * p.w; }" +
  " gl_Position = p; }"));
gl.attachShader(prog, shader(gl.FRAGMENT_SHADER,
  "precision mediump float; varying vec4 vFront; varying vec4 vBack;" +
  "vec3 enc(vec3 l) { l = clamp(l, 0.0, 1.0);" +
  " return mix(12.92 * l, 1.055 * pow(l, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, l)); }" +
  // the back of a one-sided element is not drawn: one sees into a closed room from outside
  "void main() { if (gl_FrontFacing) { gl_FragColor = vec4(enc(vFront.rgb), 1.0); }" +
  " else { if (vBack.a < 0.5) discard; gl_FragColor = vec4(enc(vBack.rgb), 1.0); } }"));
gl.linkProgram(prog);
if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
gl.useProgram(prog);
function attrib(name, data, size, type, norm) {
  var b = gl.createBuffer(), loc = gl.getAttribLocation(prog, name);
  gl.bindBuffer(gl.ARRAY_BUFFER, b); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
  gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, size, type, norm, 0, 0);
  return b;
}
function rebind(name, b) {
  var loc = gl.getAttribLocation(prog, name);
  gl.bindBuffer(gl.ARRAY_BUFFER, b);
  gl.vertexAttribPointer(loc, 4, gl.UNSIGNED_BYTE, true, 0, 0);
}
attrib("aPos", P, 3, gl.FLOAT, false);
attrib("aCen", Q, 3, gl.FLOAT, false);
var bufL = lux ? [attrib("aFront", FL, 4, gl.UNSIGNED_BYTE, true),
                  attrib("aBack", BL, 4, gl.UNSIGNED_BYTE, true)] : null;
var bufR = [attrib("aFront", F, 4, gl.UNSIGNED_BYTE, true),
            attrib("aBack", B, 4, gl.UNSIGNED_BYTE, true)];
P = Q = F = B = FL = BL = null;
var luxMode = false;
function setMode(on) {
  luxMode = !!(on && bufL);
  var b = luxMode ? bufL : bufR;
  rebind("aFront", b[0]); rebind("aBack", b[1]);
  document.getElementById("legend").style.display = luxMode ? "block" : "none";
  document.body.setAttribute("data-mode", luxMode ? "lux" : "radiance");
}
window.addEventListener("keydown", function (e) {
  if (bufL && (e.key === "l" || e.key === "L")) { setMode(!luxMode); redraw(); }
});
var uMVP = gl.getUniformLocation(prog, "uMVP"), uPx = gl.getUniformLocation(prog, "uPx");
gl.enable(gl.DEPTH_TEST);
gl.clearColor(0.118, 0.133, 0.153, 1.0);

// orbit camera about the bounding-box centre (the origin of the embedded coordinates)
function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}
function unit(a) { var n = Math.sqrt(dot(a, a)) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }
var U = unit(META.up), FH = unit(META.forward), RH = cross(FH, U);
var R = META.radius, FOV = 45 * Math.PI / 180, view = {};
function reset() {
  view.yaw = META.yaw; view.pitch = META.pitch;
  var aspect = canvas.clientWidth / Math.max(1, canvas.clientHeight);
  var half = Math.min(FOV / 2, Math.atan(Math.tan(FOV / 2) * aspect));
  view.dist = 1.05 * R / Math.sin(half);
  // a view given in the address: #yaw=DEG&pitch=DEG&zoom=F (yaw from the initial one)
  var q = {};
  (location.hash || "").replace(/^#/, "").split("&").forEach(function (kv) {
    var p = kv.split("="); if (p.length == 2) q[p[0]] = parseFloat(p[1]);
  });
  if (isFinite(q.yaw)) view.yaw = META.yaw + q.yaw * Math.PI / 180;
  if (isFinite(q.pitch)) view.pitch = Math.max(-1.55, Math.min(1.55, q.pitch * Math.PI / 180));
  if (isFinite(q.zoom) && q.zoom > 0) view.dist /= q.zoom;
}
function matrix() {
  var cp = Math.cos(view.pitch), d = [0, 0, 0];
  for (var a = 0; a < 3; a++)
    d[a] = cp * (Math.cos(view.yaw) * FH[a] + Math.sin(view.yaw) * RH[a])
           + Math.sin(view.pitch) * U[a];
  var eye = [-view.dist * d[0], -view.dist * d[1], -view.dist * d[2]];
  var z = unit(sub(eye, [0, 0, 0])), x = unit(cross(U, z)), y = cross(z, x);
  var near = Math.max(view.dist - 1.5 * R, 1e-3 * R), far = view.dist + 1.5 * R;
  var aspect = canvas.width / Math.max(1, canvas.height), f = 1 / Math.tan(FOV / 2);
  var Vw = [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
            -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
  var Pr = [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
            0, 0, 2 * far * near / (near - far), 0];
  var M = new Float32Array(16);
  for (var c = 0; c < 4; c++) for (var r = 0; r < 4; r++) {
    var s = 0; for (var e = 0; e < 4; e++) s += Pr[4 * e + r] * Vw[4 * c + e]; M[4 * c + r] = s;
  }
  return M;
}
var pending = false, drawn = false;
function draw() {
  pending = false;
  var dpr = window.devicePixelRatio || 1;
  var w = Math.max(1, Math.round(canvas.clientWidth * dpr));
  var h = Math.max(1, Math.round(canvas.clientHeight * dpr));
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  gl.viewport(0, 0, w, h);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.uniformMatrix4fv(uMVP, false, matrix());
  gl.uniform2f(uPx, 2 / w, 2 / h);
  gl.drawArrays(gl.TRIANGLES, 0, ntri * 3);
  if (!drawn) {
    gl.finish(); drawn = true;
    var err = gl.getError();
    report(err ? "error: WebGL error " + err : "ok " + ntri + " triangles");
  }
}
function redraw() { if (!pending) { pending = true; requestAnimationFrame(draw); } }

var drag = null;
canvas.addEventListener("pointerdown", function (e) {
  drag = [e.clientX, e.clientY];
  canvas.setPointerCapture(e.pointerId); canvas.style.cursor = "grabbing";
});
canvas.addEventListener("pointermove", function (e) {
  if (!drag) return;
  view.yaw -= 0.008 * (e.clientX - drag[0]);
  view.pitch = Math.max(-1.55, Math.min(1.55, view.pitch + 0.008 * (e.clientY - drag[1])));
  drag = [e.clientX, e.clientY]; redraw();
});
function release() { drag = null; canvas.style.cursor = "grab"; }
canvas.addEventListener("pointerup", release);
canvas.addEventListener("pointercancel", release);
canvas.addEventListener("wheel", function (e) {
  e.preventDefault();
  view.dist = Math.max(0.02 * R, Math.min(50 * R, view.dist * Math.exp(0.0015 * e.deltaY)));
  redraw();
}, {passive: false});
canvas.addEventListener("dblclick", function () { reset(); redraw(); });
window.addEventListener("resize", redraw);
setMode(/(^#|&)lux=1/.test(location.hash || "")); reset(); draw();
} catch (err) { report("error: " + err.message); }
})();
</script>
</body></html>
"""


#: The lux mode's false colours (sRGB, viridis' stops), from 0 to the scale's top.
_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]],
                 np.float64)


def false_colour(t: np.ndarray) -> np.ndarray:
    """sRGB bytes (..., 3) uint8 of values t (...) on the _RAMP, 0 .. 1 (clipped)."""
    x = np.clip(np.nan_to_num(np.asarray(t, np.float64)), 0.0, 1.0) * (len(_RAMP) - 1)
    i = np.minimum(x.astype(np.int64), len(_RAMP) - 2)
    f = (x - i)[..., None]
    return np.round(_RAMP[i] * (1 - f) + _RAMP[i + 1] * f).astype(np.uint8)


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def _view_frame(camera: Camera | None):
    """Orbit frame for the viewer: world up (the axis nearest the camera's up), the horizontal
    forward direction, and the initial pitch (the camera's view direction when given)."""
    if camera is None:
        return [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], 0.6, -0.35
    cy = np.asarray(camera.y, float)
    a = int(np.argmax(np.abs(cy)))
    up = np.zeros(3)
    up[a] = math.copysign(1.0, cy[a])
    z = np.asarray(camera.z, float) / np.linalg.norm(camera.z)
    pitch = math.asin(float(np.clip(z @ up, -1.0, 1.0)))
    fh = z - (z @ up) * up
    if np.linalg.norm(fh) < 1e-6:  # looking straight up or down
        fh = np.asarray(camera.y, float) * (-1.0 if z @ up < 0 else 1.0)
        fh = fh - (fh @ up) * up
    fh /= np.linalg.norm(fh)
    return up.tolist(), fh.tolist(), 0.0, max(-1.55, min(1.55, pitch))


def write_viewer(path_html: str, part: Partition, radiance: np.ndarray, exposure: float | None,
                 title: str, camera: Camera | None = None, two_sided: np.ndarray | None = None,
                 max_triangles: int = VIEWER_MAX_TRIANGLES,
                 smooth: SmoothMesh | None = None, lux: np.ndarray | None = None) -> dict:
    """A self-contained WebGL1 page showing the sub-elements with their tone-mapped radiance.

    Embeds per sub-element its 4 vertices (float32, relative to the bounding-box centre), its
    vertex count and 25 bytes: per corner [front sRGB, back sRGB], then the two-sided flag, as
    base64; the page expands them to triangles and interpolates the corner colours in linear
    radiance. smooth: a core.smooth.SmoothMesh of the same partition and radiance, whose
    vertex radiance colours the corners (as in mesh.glb); None: each sub-element's own
    (flat) colour at all its corners. radiance (m, 2, 3) linear; exposure as in `tonemap`
    (None: automatic over the front radiances). two_sided (m,) bool: draw the back colour on
    the back; one-sided backs are not drawn (closed rooms can be seen into from outside).
    camera: initial view direction (default: an oblique view); the view is fitted to the
    bounding box. Above `max_triangles` only every s-th sub-element is embedded and the page
    says so. The page sets `#status` to "ok N triangles" after the first frame (or
    "error: ..."). No external URL. lux (m, 2) lx per sub-element and side (the tables'
    illuminance): key L (or `#lux=1` in the address) shows it in false colour, flat per
    sub-element, 0 .. its 99th percentile, with a scale. Returns {"triangles", "stride",
    "bytes", "smooth"}.
    """
    radiance = np.asarray(radiance, np.float64)
    m = len(part)
    if exposure is None:
        exposure = auto_exposure(radiance[:, 0])
    ntri = int(np.sum(np.asarray(part.nverts, np.int64) - 2))
    stride = max(1, math.ceil(ntri / max(1, int(max_triangles))))
    keep = np.arange(0, m, stride)
    lo, hi = part.verts.reshape(-1, 3).min(0), part.verts.reshape(-1, 3).max(0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12)
    pos = (part.verts[keep] - centre).astype("<f4")
    nv = np.asarray(part.nverts)[keep].astype(np.uint8)
    corner_rad = np.repeat(radiance[keep][:, None], 4, axis=1)          # (k, 4, 2, 3)
    if smooth is not None:
        cv = smooth.corner[keep].transpose(0, 2, 1)                       # (k, 4, 2)
        corner_rad = np.where((cv >= 0)[..., None], smooth.radiance[np.maximum(cv, 0)],
                              corner_rad)
    col = np.zeros((len(keep), 25), np.uint8)
    col[:, :24] = tonemap(corner_rad, exposure).reshape(-1, 24)
    if two_sided is not None:
        col[:, 24] = np.asarray(two_sided, bool)[keep]
    luxcol, luxmax = np.zeros((0, 6), np.uint8), 0.0
    if lux is not None:
        L = np.nan_to_num(np.asarray(lux, np.float64)[keep])
        luxmax = float(np.percentile(L[:, 0], 99)) if len(L) else 0.0
        luxcol = false_colour(L / (luxmax or 1.0)).reshape(-1, 6)
    up, fwd, yaw, pitch = _view_frame(camera)
    shown = int(np.sum(nv.astype(np.int64) - 2))
    meta = {"grow_px": VIEWER_GROW_PX, "up": up, "forward": fwd, "yaw": yaw, "pitch": pitch,
            "radius": radius, "smooth": smooth is not None,
            "centre": centre.tolist(), "exposure": exposure, "elements": m, "triangles": shown,
            "lux": lux is not None, "lux_max": luxmax}
    caption = (f"{m:,} elements, {ntri:,} triangles &middot; exposure {exposure:.4g} "
               f"&middot; radiosity colours{' (smooth)' if smooth is not None else ''}, "
               f"one-sided backs hidden")
    warning = ""
    if stride > 1:
        warning = (f"large mesh: showing every {stride}th element ({shown:,} of {ntri:,} "
                   f"triangles)<br>")
    page = _VIEWER % {
        "title": html.escape(str(title)), "caption": caption, "warning": warning,
        "pos": _b64(pos), "nv": _b64(nv), "col": _b64(col), "lux": _b64(luxcol),
        "luxhelp": "L: illuminance (lx) / radiance" if lux is not None else "",
        "luxmax": f"{luxmax:.4g}", "ramp": ",".join(
            "#%02x%02x%02x" % tuple(int(v) for v in c) for c in _RAMP),
        "meta": json.dumps(meta).replace("</", "<\\/"),
    }
    tmp = temp_path(path_html)
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(page)
    os.replace(tmp, path_html)
    return {"triangles": shown, "stride": stride, "bytes": len(page), "smooth": smooth is not None}
