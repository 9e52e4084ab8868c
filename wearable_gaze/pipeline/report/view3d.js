// The report's 3D view (wearable_gaze/pipeline/report/view3d.py inlines this file and its scene as JSON).
// Canvas 2D, no library, no network: works offline and without a GPU. Drag turns the view about
// the scene's centre, shift-drag (or the right button) pans, the wheel zooms, a double click resets. World frame of the marker map, mm;
// "up" is the scene's up vector (-y: OpenCV's y points down).
(function () {
  "use strict";
  const canvas = document.getElementById("view3d");
  const scene = JSON.parse(document.getElementById("view3d-data").textContent);
  const ctx = canvas.getContext("2d");
  const show = {markers: true, head: true, lines: true, regions: true, truth: true, aois: true};
  const home = {yaw: -0.35, pitch: 0.55, zoom: 1.0, panX: 0, panY: 0};   // from behind the head, above
  let view = Object.assign({}, home);

  // the centre and size of what is looked at: the box of the head path and the targets (the room
  // may be far larger, a region's far end too)
  const focus = [];
  if (scene.box) [0, 1].forEach(i => [0, 1].forEach(j => [0, 1].forEach(k =>
    focus.push([scene.box[i][0], scene.box[j][1], scene.box[k][2]]))));
  scene.head.forEach(p => focus.push(p));
  scene.targets.forEach(t => {
    if (t.position) focus.push(t.position);
    if (t.truth) focus.push(t.truth);
    (t.path || []).forEach(p => focus.push(p));
  });
  if (!focus.length) scene.markers.forEach(m => m.corners.forEach(p => focus.push(p)));
  const lo = [0, 1, 2].map(k => Math.min(...focus.map(p => p[k])));
  const hi = [0, 1, 2].map(k => Math.max(...focus.map(p => p[k])));
  const centre = focus.length ? lo.map((v, k) => (v + hi[k]) / 2) : [0, 0, 0];
  // a box's corners are never all in line: its half-diagonal would leave the scene small
  const radius = focus.length ? Math.max(300, (scene.box ? 0.35 : 0.5) * Math.hypot(hi[0] - lo[0], hi[1] - lo[1],
                                                                                     hi[2] - lo[2])) : 1000;
  const up = scene.up;                     // a unit vector; the view's vertical
  const fwd0 = Math.abs(up[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const norm = a => { const n = Math.hypot(a[0], a[1], a[2]); return [a[0] / n, a[1] / n, a[2] / n]; };
  const right0 = norm(cross(fwd0, up));    // horizontal axes of the view before it is turned:
  const ahead0 = cross(up, right0);        // right, up, ahead as the viewer sees them (not mirrored)

  let W = 0, H = 0, f = 1, dist = 1;
  function resize() {
    const r = window.devicePixelRatio || 1;
    const w = canvas.clientWidth || 800, h = canvas.clientHeight || 560;
    canvas.width = Math.round(w * r);
    canvas.height = Math.round(h * r);
    W = canvas.width; H = canvas.height;
  }

  // world point (mm) -> [x px, y px, depth mm] (depth <= 0: behind the viewer)
  function toView(p) {
    const d = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]];
    const a = dot(d, right0), b = dot(d, ahead0), u = dot(d, up);
    const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw), cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
    const x = cy * a - sy * b, z1 = sy * a + cy * b;                   // turned about the vertical
    const y = cp * u + sp * z1, z = cp * z1 - sp * u;                  // tilted: pitch > 0 looks down
    return [x - view.panX, y - view.panY, z + dist];         // panned across the view
  }
  const near = () => 0.02 * dist;
  function screen(v) { return [W / 2 + f * v[0] / v[2], H / 2 - f * v[1] / v[2]]; }

  let drawn = 0;
  function segment(a, b) {                  // a line clipped at the near plane
    let va = toView(a), vb = toView(b);
    const n = near();
    if (va[2] < n && vb[2] < n) return;
    if (va[2] < n || vb[2] < n) {
      const s = (n - va[2]) / (vb[2] - va[2]);
      const c = [va[0] + s * (vb[0] - va[0]), va[1] + s * (vb[1] - va[1]), n];
      if (va[2] < n) va = c; else vb = c;
    }
    const pa = screen(va), pb = screen(vb);
    ctx.moveTo(pa[0], pa[1]);
    ctx.lineTo(pb[0], pb[1]);
    drawn += 1;
  }
  function polyline(pts, closed) {
    for (let i = 1; i < pts.length; i++) segment(pts[i - 1], pts[i]);
    if (closed && pts.length > 2) segment(pts[pts.length - 1], pts[0]);
  }
  function stroke(colour, width, alpha, dash) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = width * (window.devicePixelRatio || 1);
    ctx.globalAlpha = alpha;
    ctx.setLineDash(dash || []);
    ctx.stroke();
    ctx.beginPath();
    ctx.globalAlpha = 1;
    ctx.setLineDash([]);
  }
  function dotAt(p, colour, size, shape) {
    const v = toView(p);
    if (v[2] < near()) return null;
    const s = screen(v), r = size * (window.devicePixelRatio || 1);
    ctx.beginPath();
    if (shape === "square") ctx.rect(s[0] - r, s[1] - r, 2 * r, 2 * r);
    else ctx.arc(s[0], s[1], r, 0, 2 * Math.PI);
    if (shape === "square") { ctx.lineWidth = 2 * (window.devicePixelRatio || 1); ctx.strokeStyle = colour; ctx.stroke(); }
    else { ctx.fillStyle = colour; ctx.fill(); }
    ctx.beginPath();
    drawn += 1;
    return s;
  }
  function label(s, text, colour) {
    if (!s) return;
    const r = window.devicePixelRatio || 1;
    ctx.font = `${Math.round(12 * r)}px sans-serif`;
    const w = ctx.measureText(text).width;
    const x = Math.min(Math.max(s[0] + 8 * r, 2), W - w - 2), y = Math.min(Math.max(s[1] - 8 * r, 14 * r), H - 4);
    ctx.fillStyle = colour;
    ctx.fillText(text, x, y);
  }
  function arrowHead(a, b) {                // a screen-space arrowhead at b, pointing from a
    const va = toView(a), vb = toView(b);
    if (va[2] < near() || vb[2] < near()) return;
    const pa = screen(va), pb = screen(vb), r = window.devicePixelRatio || 1;
    const L = Math.hypot(pb[0] - pa[0], pb[1] - pa[1]);
    if (L < 1) return;
    const ux = (pb[0] - pa[0]) / L, uy = (pb[1] - pa[1]) / L, s = 11 * r;
    ctx.moveTo(pb[0] - s * ux + 0.5 * s * uy, pb[1] - s * uy - 0.5 * s * ux);
    ctx.lineTo(pb[0], pb[1]);
    ctx.lineTo(pb[0] - s * ux - 0.5 * s * uy, pb[1] - s * uy + 0.5 * s * ux);
    drawn += 1;
  }
  function region(t) {                      // rings and edges; dashed: no far end; arrow: runs on
    const g = t.region, dash = g.open ? [7, 5] : [];
    g.rings.forEach(r => polyline(r, true));
    g.sides.forEach(s => segment(s[0], s[1]));
    stroke(t.colour, 1.3, 0.9, dash);
    segment(g.axis[0], g.axis[1]);
    stroke(t.colour, 0.9, 0.7, dash);
    if (g.cut) { arrowHead(g.axis[0], g.axis[1]); stroke(t.colour, 1.8, 1); }
  }
  function ellipse(c, a, b) {
    const pts = [];
    for (let i = 0; i < 48; i++) {
      const t = 2 * Math.PI * i / 48, ca = Math.cos(t), sb = Math.sin(t);
      pts.push([c[0] + ca * a[0] + sb * b[0], c[1] + ca * a[1] + sb * b[1], c[2] + ca * a[2] + sb * b[2]]);
    }
    polyline(pts, true);
  }

  function draw() {
    const dist0 = 3.2 * radius;             // at zoom 1 the focus sphere fills 90 % of the view
    f = 0.45 * Math.min(W, H) * dist0 / radius;
    dist = dist0 / view.zoom;               // zooming walks in
    drawn = 0;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, W, H);
    ctx.beginPath();
    let points = 0, aois = 0;                  // what each layer drew (tests and benchmarks read them)
    if (show.markers) {
      scene.markers.forEach(m => polyline(m.corners, true));
      stroke("#555555", 1.2, 0.9);
      const r = window.devicePixelRatio || 1;
      (scene.points || []).forEach(p => {       // a markerless map's points: small grey squares
        const v = toView(p);
        if (v[2] < near()) return;
        const s = screen(v);
        ctx.rect(s[0] - r, s[1] - r, 2 * r, 2 * r);
        drawn += 1;
        points += 1;
      });
      ctx.globalAlpha = 0.45;
      ctx.fillStyle = "#8a8f96";
      ctx.fill();
      ctx.globalAlpha = 1;
      ctx.beginPath();
    }
    const o = scene.origin, ax = 300;
    // the axes in grey, not red, green, blue: those are the targets' colours
    [["x", "#444444", [ax, 0, 0]], ["y", "#444444", [0, ax, 0]], ["z", "#444444", [0, 0, ax]]].forEach(([n, c, e]) => {
      segment(o, [o[0] + e[0], o[1] + e[1], o[2] + e[2]]);
      stroke(c, 2, 1);
      const v = toView([o[0] + e[0], o[1] + e[1], o[2] + e[2]]);
      if (v[2] > near()) label(screen(v), n, c);
    });
    if (show.head) {
      polyline(scene.head, false);
      stroke("#000000", 1.5, 1);
      if (show.truth && scene.truth_head) { polyline(scene.truth_head, false); stroke("#000000", 1, 0.6, [4, 4]); }
    }
    scene.targets.forEach(t => {
      if (show.lines) { t.lines.forEach(l => segment(l[0], l[1])); stroke(t.colour, 0.8, 0.35); }
      if (t.path) { polyline(t.path, false); stroke(t.colour, 3, 1); }
      if (show.regions && t.region) region(t);
      if (show.regions && !t.region && t.position && t.ellipsoid) {
        const [a, b, c] = t.ellipsoid;
        ellipse(t.position, a, b); ellipse(t.position, b, c); ellipse(t.position, a, c);
        stroke(t.colour, 1.2, 0.9);
      }
      if (show.truth && t.truth_path) { polyline(t.truth_path, false); stroke(t.colour, 1.5, 0.9, [6, 4]); }
      if (show.truth && t.truth && t.position) { segment(t.position, t.truth); stroke("#000000", 1, 0.8, [3, 3]); }
    });
    scene.targets.forEach(t => {
      let s = t.position ? dotAt(t.position, t.colour, 5) : null;
      if (!s && t.region) {                 // a direction without a point: its label on the line of sight
        const v = toView(t.region.axis[0].map((x, k) => 0.5 * (x + t.region.axis[1][k])));
        s = v[2] > near() ? screen(v) : null;
      }
      if (show.truth && t.truth) dotAt(t.truth, t.colour, 5, "square");
      label(s, t.label, t.colour);
    });
    const named = [];                          // the areas' labels placed: [x, y, width] px
    if (show.aois) (scene.aois || []).forEach(a => {
      const before = drawn;
      a.segments.forEach(l => segment(l[0], l[1]));
      aois += drawn - before;
      stroke(a.colour, 1.6, 0.9, [5, 3]);
      const c = [0, 1, 2].map(k => a.segments.reduce((acc, l) => acc + l[0][k] + l[1][k], 0) / (2 * a.segments.length));
      const v = toView(c);
      if (v[2] <= near()) return;
      // a label over one already placed would make both unreadable: it is left out (zoom in to see it)
      const s = screen(v), r = window.devicePixelRatio || 1;
      ctx.font = `${Math.round(12 * r)}px sans-serif`;
      const w = ctx.measureText(a.name).width;
      if (named.some(([x, y, wn]) => s[0] < x + wn && x < s[0] + w && Math.abs(s[1] - y) < 14 * r)) return;
      named.push([s[0], s[1], w]);
      label(s, a.name, a.colour);
    });
    if (show.truth) (scene.other_truth || []).forEach(u => label(dotAt(u.position, "#000000", 5, "square"), u.label, "#000000"));
    canvas.dataset.drawn = String(drawn);
    canvas.dataset.drawnPoints = String(points);
    canvas.dataset.drawnAois = String(aois);
    canvas.dataset.aoiLabels = String(named.length);
  }

  function redraw() { resize(); draw(); }
  let drag = null;
  canvas.addEventListener("pointerdown", e => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("contextmenu", e => e.preventDefault());      // the right button pans
  canvas.addEventListener("pointermove", e => {
    if (!drag) return;
    const dx = e.clientX - drag[0], dy = e.clientY - drag[1];
    if (e.shiftKey || (e.buttons & 2)) {       // pan: the scene follows the pointer at the focus's depth
      const r = window.devicePixelRatio || 1;
      view.panX -= dx * r * dist / f;
      view.panY += dy * r * dist / f;
    } else {
      view.yaw += 0.01 * dx;
      view.pitch = Math.max(-1.55, Math.min(1.55, view.pitch + 0.01 * dy));
    }
    drag = [e.clientX, e.clientY];
    draw();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("wheel", e => {
    e.preventDefault();
    view.zoom = Math.max(0.2, Math.min(20, view.zoom * Math.exp(-0.0015 * e.deltaY)));
    draw();
  }, {passive: false});
  canvas.addEventListener("dblclick", () => { view = Object.assign({}, home); draw(); });
  document.querySelectorAll("input[data-layer]").forEach(box => {
    box.addEventListener("change", () => { show[box.dataset.layer] = box.checked; draw(); });
  });
  window.addEventListener("resize", redraw);
  redraw();
})();
