// refine serve: the cell in 3D (three.js), the robot along the path, and the gizmo that drags a frame.
// Positions are in the world frame {F} [m], z up. A robot shape's pose arrives as the 12 numbers of
// the top three rows of its 4x4 transform (row-major); a frame's pose as {xyz [m], rpy_deg [deg]}
// with fixed-axis X-Y-Z angles, R = Rz(rz) Ry(ry) Rx(rx), which is three.js's Euler order "ZYX".
// Lines are three.js's fat lines (Line2, LineSegments2): WebGL draws its own lines 1 px wide
// whatever the width asked; these are quads of WIDTH_PX pixels on the screen at any zoom.
import * as THREE from "three";
import { OrbitControls } from "three/addons/OrbitControls.js";
import { TransformControls } from "three/addons/TransformControls.js";
import { Line2 } from "three/addons/lines/Line2.js";
import { LineGeometry } from "three/addons/lines/LineGeometry.js";
import { LineMaterial } from "three/addons/lines/LineMaterial.js";
import { LineSegments2 } from "three/addons/lines/LineSegments2.js";
import { LineSegmentsGeometry } from "three/addons/lines/LineSegmentsGeometry.js";

export const WIDTH_PX = { path: 4, demo: 3, motion: 3, axis: 1.5 };   // line widths on the screen [px]

function fatLine(points, width, color, colors) {   // a Line2 through points [x0, y0, z0, x1, ...]
  const p = points.length >= 6 ? points : points.concat(points);   // one point: a dot of zero length
  const g = new LineGeometry();
  g.setPositions(p);
  if (colors) { g.setColors(colors.length === p.length ? colors : colors.concat(colors)); }
  return new Line2(g, new LineMaterial({ color: colors ? 0xffffff : color, linewidth: width, vertexColors: !!colors, worldUnits: false }));
}

function fatSegments(points, width, color) {   // LineSegments2 of the pairs of points
  const g = new LineSegmentsGeometry();
  g.setPositions(points);
  return new LineSegments2(g, new LineMaterial({ color, linewidth: width, worldUnits: false }));
}

export function linePoints(o) {   // the points a line (fat or not) is drawn through, [[x, y, z], ...]
  const start = o.geometry.getAttribute("instanceStart"), end = o.geometry.getAttribute("instanceEnd");
  const p = [];
  if (!start) {
    const a = o.geometry.getAttribute("position");
    for (let k = 0; k < a.count; k++) { p.push([a.getX(k), a.getY(k), a.getZ(k)]); }
    return p;
  }
  for (let k = 0; k < start.count; k++) { p.push([start.getX(k), start.getY(k), start.getZ(k)]); }
  if (start.count) { p.push([end.getX(start.count - 1), end.getY(start.count - 1), end.getZ(start.count - 1)]); }
  return p;
}

const HOVER_PX = 8;   // how near the pointer a waypoint must be drawn for its label [px]

const VIRIDIS = [[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
  [31, 158, 137], [53, 183, 121], [109, 205, 89], [180, 222, 44], [253, 231, 37]];

export function viridis(t) {
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1), a = Math.floor(x), b = Math.min(a + 1, VIRIDIS.length - 1);
  const w = x - a, c = VIRIDIS[a].map((v, k) => (v + (VIRIDIS[b][k] - v) * w) / 255);
  return new THREE.Color(c[0], c[1], c[2]);
}

export function rowMatrix(m) {
  return new THREE.Matrix4().set(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], 0, 0, 0, 1);
}

export function poseMatrix(pose) {
  const r = pose.rpy_deg.map((d) => THREE.MathUtils.degToRad(d));
  const m = new THREE.Matrix4().makeRotationFromEuler(new THREE.Euler(r[0], r[1], r[2], "ZYX"));
  m.setPosition(pose.xyz[0], pose.xyz[1], pose.xyz[2]);
  return m;
}

export function matrixPose(m) {   // rounded as the problem file keeps a pose (a micrometre, 1e-5 deg)
  const p = new THREE.Vector3(), q = new THREE.Quaternion(), s = new THREE.Vector3();
  m.decompose(p, q, s);
  const e = new THREE.Euler().setFromQuaternion(q, "ZYX");
  const round = (v, d) => Math.round(v * 10 ** d) / 10 ** d + 0;
  return { xyz: [p.x, p.y, p.z].map((v) => round(v, 6)), rpy_deg: [e.x, e.y, e.z].map((v) => round(THREE.MathUtils.radToDeg(v), 5)) };
}

function meshGeometry(o) {
  const n = o.x.length, pos = new Float32Array(n * 3), index = [];
  for (let a = 0; a < n; a++) { pos[3 * a] = o.x[a]; pos[3 * a + 1] = o.y[a]; pos[3 * a + 2] = o.z[a]; }
  for (let f = 0; f < o.i.length; f++) { index.push(o.i[f], o.j[f], o.k[f]); }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
  g.setIndex(index);
  const flat = g.toNonIndexed();
  flat.computeVertexNormals();
  g.dispose();
  return flat;
}

function dispose(group) {
  group.traverse((o) => { if (o.geometry) { o.geometry.dispose(); } if (o.material) { o.material.dispose(); } });
  group.clear();
}

export class View {
  constructor(div, onDrag) {
    this.div = div;
    this.onDrag = onDrag;            // (target, matrix, done) when the gizmo moves a frame
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setClearColor(0xffffff);
    div.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    this.camera.up.set(0, 0, 1);
    this.scene.add(new THREE.AmbientLight(0xffffff, 1.4));
    const sun = new THREE.DirectionalLight(0xffffff, 1.8);
    sun.position.set(2, -3, 4);
    this.scene.add(sun);
    this.scene.add(new THREE.AxesHelper(0.3));
    this.groups = {};
    for (const name of ["cell", "robot", "paths", "frames", "motions", "demo"]) { this.groups[name] = new THREE.Group(); this.scene.add(this.groups[name]); }
    this.orbit = new OrbitControls(this.camera, this.renderer.domElement);
    this.orbit.addEventListener("change", () => this.render());
    this.handle = new THREE.Object3D();
    this.scene.add(this.handle);
    this.gizmo = new TransformControls(this.camera, this.renderer.domElement);
    this.gizmo.setSize(0.8);
    this.scene.add(this.gizmo.getHelper());
    this.gizmo.addEventListener("change", () => this.render());
    this.gizmo.addEventListener("dragging-changed", (ev) => {
      this.orbit.enabled = !ev.value;
      if (!ev.value && this.target) { this.handle.updateMatrix(); this.onDrag(this.target, this.handle.matrix.clone(), true); }
    });
    this.gizmo.addEventListener("objectChange", () => {
      if (!this.target) { return; }
      this.handle.updateMatrix();
      this.onDrag(this.target, this.handle.matrix.clone(), false);
    });
    this.target = null;
    this.fitted = false;
    this.hover = null;              // (text, x, y) for the label of the waypoint under the pointer, or null
    this.renderer.domElement.addEventListener("pointermove", (ev) => this.pointed(ev));
    this.renderer.domElement.addEventListener("pointerleave", () => { if (this.onHover) { this.onHover(null, 0, 0); } });
    this.robotMeshes = [];
    new ResizeObserver(() => this.resize()).observe(div);
    this.resize();
  }

  resize() {
    const w = Math.max(this.div.clientWidth, 10), h = Math.max(this.div.clientHeight, 10);
    this.renderer.setSize(w, h, false);
    this.renderer.domElement.style.width = w + "px";
    this.renderer.domElement.style.height = h + "px";
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    if (this.pending) { return; }
    this.pending = true;
    requestAnimationFrame(() => { this.pending = false; this.renderer.render(this.scene, this.camera); });
  }

  setCell(cell) {
    dispose(this.groups.cell);
    for (const o of cell) {
      const work = o.kind === "workpiece";
      const mesh = new THREE.Mesh(meshGeometry(o), new THREE.MeshLambertMaterial({
        color: work ? 0x7fb3d5 : 0xb0b0b0, transparent: true, opacity: work ? 0.7 : 0.45, side: THREE.DoubleSide, depthWrite: !work }));
      mesh.name = o.name;
      this.groups.cell.add(mesh);
    }
    this.render();
  }

  setParts(parts) {
    dispose(this.groups.robot);
    const visual = parts.some((p) => p.kind === "visual");
    this.robotMeshes = parts.map((part) => {
      const collision = part.kind === "robot" && visual;
      const mesh = new THREE.Mesh(meshGeometry(part), new THREE.MeshLambertMaterial({ color: part.kind === "tool" ? 0x505050 : (collision ? 0x5dade2 : 0xf39c12),
        transparent: collision, opacity: collision ? 0.75 : 1 }));
      mesh.name = part.name;
      // with visual meshes, the robot is drawn either by them or by its collision shapes (on demand)
      mesh.userData.shown = part.kind === "visual" ? "visual" : (collision ? "collision" : "always");
      mesh.visible = this.robotShown(mesh);
      mesh.matrixAutoUpdate = false;
      this.groups.robot.add(mesh);
      return mesh;
    });
  }

  robotShown(mesh) {
    const kind = mesh.userData.shown;
    return kind === "always" || (kind === "collision") === (this.showCollision === true);
  }

  showRobot(frame) {   // frame: one 12-number pose per part
    this.robotMeshes.forEach((mesh, p) => { mesh.matrix.copy(rowMatrix(frame[p])); mesh.matrixWorldNeedsUpdate = true; });
    this.render();
  }

  setPaths(paths, quantity) {   // the paths coloured by ``quantity``; the colour bar's range and a note
    dispose(this.groups.paths);
    let note = "", range = null;
    for (const path of paths) {
      const n = path.x.length, pos = new Float32Array(n * 3), col = new Float32Array(n * 3);
      const entry = path.quantities[quantity], values = entry && !entry.missing ? entry.values : null;
      if (entry && entry.missing) { note = entry.missing; }
      let lo = Infinity, hi = -Infinity;
      if (values) { for (const v of values) { if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); } } }
      if (values) { range = { lo, hi, title: entry.title }; }
      for (let a = 0; a < n; a++) {
        pos.set([path.x[a], path.y[a], path.z[a]], 3 * a);
        const c = values && values[a] !== null ? viridis(hi > lo ? (values[a] - lo) / (hi - lo) : 0.5) : new THREE.Color(0x1f77b4);
        col.set([c.r, c.g, c.b], 3 * a);
      }
      const line = fatLine(Array.from(pos), WIDTH_PX.path, null, Array.from(col));   // coloured per waypoint
      line.name = path.name + " (" + path.status + ")";
      this.groups.paths.add(line);
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
      g.setAttribute("color", new THREE.BufferAttribute(col, 3));
      const dots = new THREE.Points(g, new THREE.PointsMaterial({ vertexColors: true, size: 6, sizeAttenuation: false }));
      dots.name = "waypoints";   // what the pointer picks (and a dot at each waypoint)
      this.groups.paths.add(dots);
      const axis = [];
      for (let a = 0; a + 1 < path.axis.x.length; a += 3) {
        axis.push(path.axis.x[a], path.axis.y[a], path.axis.z[a], path.axis.x[a + 1], path.axis.y[a + 1], path.axis.z[a + 1]);
      }
      if (axis.length) {
        const axes = fatSegments(axis, WIDTH_PX.axis, 0x555555);
        axes.name = "tool axis";
        this.groups.paths.add(axes);
      }
      for (const mark of path.marks) {
        const p = [];
        for (const k of mark.index) { p.push(path.x[k], path.y[k], path.z[k]); }
        const gm = new THREE.BufferGeometry();
        gm.setAttribute("position", new THREE.Float32BufferAttribute(p, 3));
        const m = new THREE.Points(gm, new THREE.PointsMaterial({ color: mark.kind === "infeasible" ? 0xe74c3c : 0xe67e22, size: 9, sizeAttenuation: false }));
        m.name = mark.label;
        this.groups.paths.add(m);
      }
    }
    this.render();
    return { note, range };
  }

  polyline(o, color, name, width) {   // a fat line ``width`` px wide through o.x, o.y, o.z
    const p = [];
    for (let a = 0; a < o.x.length; a++) { p.push(o.x[a], o.y[a], o.z[a]); }
    const line = fatLine(p, width, color, null);
    line.name = name;
    return line;
  }

  setMotions(motions) {   // every planned motion, its via points as dots; one may be selected
    dispose(this.groups.motions);
    this.motionLines = motions.map((m, n) => {
      const line = this.polyline(m, m.status === "ok" ? 0x8e44ad : 0xe74c3c, "motion: " + m.name + " (" + m.status + ")", WIDTH_PX.motion);
      line.userData = { index: n };
      this.groups.motions.add(line);
      if (m.via.x.length) {
        const g = new THREE.BufferGeometry();
        const p = [];
        for (let a = 0; a < m.via.x.length; a++) { p.push(m.via.x[a], m.via.y[a], m.via.z[a]); }
        g.setAttribute("position", new THREE.Float32BufferAttribute(p, 3));
        const dots = new THREE.Points(g, new THREE.PointsMaterial({ color: 0x8e44ad, size: 7, sizeAttenuation: false }));
        dots.name = "via points: " + m.name;
        this.groups.motions.add(dots);
      }
      return line;
    });
    this.select(this.selected === undefined ? null : this.selected);
  }

  select(n) {   // the motion ``n`` drawn bright, the others faint (null: all as they are)
    this.selected = n;
    (this.motionLines || []).forEach((line, k) => {
      const ok = line.name.endsWith("(ok)");
      line.material.color.set(n === null || n === k ? (ok ? 0x8e44ad : 0xe74c3c) : 0xd7c8e0);
      line.renderOrder = n === k ? 1 : 0;
    });
    this.render();
  }

  setDemo(demo) {   // the demonstration as recorded (green) and as the fusion uses it (brown)
    dispose(this.groups.demo);
    this.demoLines = {};
    const colours = { recorded: 0x27ae60, aligned: 0x8d6e63 };
    for (const key of ["recorded", "aligned"]) {
      if (!demo || !demo[key]) { continue; }
      const line = this.polyline(demo[key], colours[key], "demonstration " + key, WIDTH_PX.demo);
      this.demoLines[key] = line;
      this.groups.demo.add(line);
    }
    this.render();
  }

  showLayer(what, on) {   // "recorded", "aligned", "motions" on or off; "collision": the robot's collision shapes instead of its visual meshes
    if (what === "collision") {
      this.showCollision = on;
      this.robotMeshes.forEach((m) => { m.visible = this.robotShown(m); });
      this.render();
      return;
    }
    const o = what === "motions" ? this.groups.motions : (this.demoLines || {})[what];
    if (o) { o.visible = on; this.render(); }
  }

  waypointAt(clientX, clientY) {   // the (path, waypoint) nearest the pointer on the screen within HOVER_PX, or null
    const r = this.renderer.domElement.getBoundingClientRect();
    const x = clientX - r.left, y = clientY - r.top, v = new THREE.Vector3();
    const dots = this.groups.paths.children.filter((o) => o.name === "waypoints");
    let best = null, bestD = HOVER_PX * HOVER_PX;
    dots.forEach((o, path) => {   // in pixels, so at any zoom; the nearest to the camera wins a tie
      const a = o.geometry.getAttribute("position");
      for (let k = 0; k < a.count; k++) {
        v.set(a.getX(k), a.getY(k), a.getZ(k)).project(this.camera);
        if (v.z < -1 || v.z > 1) { continue; }   // behind the camera or beyond its far plane
        const dx = (v.x + 1) / 2 * r.width - x, dy = (1 - v.y) / 2 * r.height - y, d = dx * dx + dy * dy;
        if (d < bestD || (d === bestD && best && v.z < best.z)) { bestD = d; best = { path, index: k, z: v.z }; }
      }
    });
    return best && { path: best.path, index: best.index };
  }

  screenOfWaypoint(path, index) {   // where waypoint ``index`` of path ``path`` is on the page [px], for tests
    const dots = this.groups.paths.children.filter((o) => o.name === "waypoints")[path];
    const a = dots.geometry.getAttribute("position");
    const p = new THREE.Vector3(a.getX(index), a.getY(index), a.getZ(index)).project(this.camera);
    const r = this.renderer.domElement.getBoundingClientRect();
    return [r.left + (p.x + 1) / 2 * r.width, r.top + (1 - p.y) / 2 * r.height];
  }

  pointed(ev) {
    if (this.gizmo.dragging || !this.onHover) { return; }
    this.onHover(this.waypointAt(ev.clientX, ev.clientY), ev.clientX, ev.clientY);
  }

  setFrames(frames) {   // name -> 4x4 Matrix4 of the frames drawn as axes (and dragged by the gizmo)
    dispose(this.groups.frames);
    this.frames = frames;
    for (const [name, m] of Object.entries(frames)) {
      const axes = new THREE.AxesHelper(0.15);
      axes.name = name;
      axes.matrixAutoUpdate = false;
      axes.matrix.copy(m);
      this.groups.frames.add(axes);
    }
    if (this.target && !this.gizmo.dragging && frames[this.target]) { this.place(frames[this.target]); }
    this.render();
  }

  place(m) {
    m.decompose(this.handle.position, this.handle.quaternion, this.handle.scale);
    this.handle.updateMatrix();
  }

  attach(target, mode, zOnly) {   // the gizmo on frame ``target`` (null: none), "translate" or "rotate"
    this.target = target;
    if (!target || !this.frames || !this.frames[target]) { this.gizmo.detach(); this.render(); return; }
    this.place(this.frames[target]);
    this.gizmo.attach(this.handle);
    this.gizmo.setMode(mode);
    this.gizmo.setSpace(mode === "rotate" ? "local" : "world");
    this.gizmo.showX = this.gizmo.showY = !(zOnly && mode === "rotate");
    this.render();
  }

  screenOf(local) {   // where the gizmo's point ``local`` (world axes, in its size) is on the page [px], for tests
    const d = this.handle.position.distanceTo(this.camera.position);
    const unit = d * Math.min(1.9 * Math.tan(Math.PI * this.camera.fov / 360) / this.camera.zoom, 7) / 4 * this.gizmo.size;
    const p = new THREE.Vector3(...local).multiplyScalar(unit).add(this.handle.position).project(this.camera);
    const r = this.renderer.domElement.getBoundingClientRect();
    return [r.left + (p.x + 1) / 2 * r.width, r.top + (1 - p.y) / 2 * r.height];
  }

  names() { return [...this.groups.cell.children, ...this.groups.paths.children, ...this.groups.motions.children, ...this.groups.demo.children].map((o) => o.name).concat(this.robotMeshes.length ? ["robot"] : []); }

  fit() {   // the camera on everything drawn, once
    if (this.fitted) { return; }
    const box = new THREE.Box3().setFromObject(this.groups.cell).union(new THREE.Box3().setFromObject(this.groups.robot));
    if (box.isEmpty()) { return; }
    const c = box.getCenter(new THREE.Vector3()), r = box.getSize(new THREE.Vector3()).length() / 2;
    const eye = new THREE.Vector3(1.4, -1.6, 1.0).normalize().multiplyScalar(2.3 * r);
    this.camera.position.copy(c).add(eye);
    this.orbit.target.copy(c);
    this.orbit.update();
    this.fitted = true;
    this.render();
  }
}
