// refine serve: shows the states the server sends over the websocket and sends the changes.
// The body's data-revision is the revision of the verdict shown, data-status its status and
// data-scene the revision of the scene drawn, so a browser test can wait for them; #scene's
// data-objects lists the names of what the 3D view draws; data-first-scene-bytes and
// data-first-scene-ms the size of the first scene message [characters] and when it was drawn
// [ms after the page's start].
import { View, poseMatrix, matrixPose, rowMatrix } from "./scene3d.js";
{
  var params = new URLSearchParams(window.location.search);
  var token = params.get("token") || "";
  var CONFIG = { responsive: true, displaylogo: false };   // Plotly's, for the calibration residuals
  var $ = function (id) { return document.getElementById(id); };
  var scene = null;       // the last scene
  var values = null;      // the last values of the settings
  var socket = null;

  function url(path) { return path + (token ? (path.indexOf("?") < 0 ? "?" : "&") + "token=" + encodeURIComponent(token) : ""); }
  function api(method, path, body) {
    var init = { method: method, headers: { "Content-Type": "application/json" } };
    if (token) { init.headers["X-Refine-Token"] = token; }
    if (body !== undefined) { init.body = JSON.stringify(body); }
    return fetch(url(path), init).then(function (r) {
      return r.json().then(function (j) { if (!r.ok) { throw new Error(j.error || r.statusText); } return j; });
    });
  }
  function showError(text) { var e = $("error"); e.textContent = text || ""; e.hidden = !text; }

  // ---- the controls ---------------------------------------------------------------------------
  function send(changes) {
    showError("");
    socket.send(JSON.stringify({ type: "change", changes: changes }));
  }
  function number(input) {
    var text = input.value.trim();
    var v = Number(text);
    return text === "" || !isFinite(v) ? text : v;   // a text that is no number goes as it is: the server says why
  }
  document.querySelectorAll("input.scalar").forEach(function (input) {
    input.addEventListener("change", function () { var c = {}; c[input.dataset.key] = number(input); send(c); });
  });
  document.querySelectorAll(".pose").forEach(function (box) {
    box.addEventListener("change", function (ev) {
      var key = ev.target.dataset.key, pose = { xyz: [0, 0, 0], rpy_deg: [0, 0, 0] };
      box.querySelectorAll("input").forEach(function (i) { pose[i.dataset.part][Number(i.dataset.axis)] = number(i); });
      var c = {}; c[key] = pose; send(c);
    });
  });
  function moveValue() {   // the sliders' values over the move as last set (the gizmo sets it exactly)
    var last = values ? values.move : { xyz: [0, 0, 0], rpy_deg: [0, 0, 0] };
    var move = { xyz: last.xyz.slice(), rpy_deg: last.rpy_deg.slice() };
    document.querySelectorAll("input.move").forEach(function (i) {
      var v = Number(i.value), now = move[i.dataset.part][Number(i.dataset.axis)];
      var shown = i.dataset.part === "xyz" ? Math.round(now * 1000) : Math.round(now);
      if (v !== shown) { move[i.dataset.part][Number(i.dataset.axis)] = i.dataset.part === "xyz" ? v / 1000 : v; }
      $(i.id + "-value").textContent = i.value;
    });
    return move;
  }
  document.querySelectorAll("input.move").forEach(function (i) {
    i.addEventListener("input", function () { send({ move: moveValue() }); });   // every step of a drag: the latest wins
  });
  $("reset").addEventListener("click", function () { api("POST", "api/reset").catch(function (e) { showError(e.message); }); });
  $("show-diff").addEventListener("click", function () {
    api("GET", "api/diff").then(function (j) {
      $("diff").textContent = j.diff || "(no change to problem.toml)";
      $("diff").hidden = false; $("write").disabled = false;
    }).catch(function (e) { showError(e.message); });
  });
  $("write").addEventListener("click", function () {
    $("write").disabled = true; $("written").textContent = "writing...";
    api("POST", "api/write").then(function (j) {
      var box = $("written"); box.textContent = "";
      var p = document.createElement("p"); p.id = "write-status";
      p.textContent = "saved problem.toml and wrote " + j.files.length + " files into " + j.out + " (" + j.status + ")";
      box.appendChild(p);
      var ul = document.createElement("ul"); ul.id = "written-files";
      j.files.forEach(function (f) {
        var li = document.createElement("li"), a = document.createElement("a");
        a.href = url("files/" + encodeURIComponent(f)); a.textContent = f; a.target = "_blank";
        li.appendChild(a); ul.appendChild(li);
      });
      box.appendChild(ul); $("diff").hidden = true;
    }).catch(function (e) { $("written").textContent = ""; showError(e.message); });
  });

  var calibration = null, plotlyLoaded = null;
  function withPlotly() {   // Plotly (4.8 MB) is loaded when the first calibration is fitted, not with the page
    if (!plotlyLoaded) {
      plotlyLoaded = new Promise(function (resolve, reject) {
        var tag = document.createElement("script");
        tag.src = url("plotly.js"); tag.onload = resolve; tag.onerror = function () { reject(new Error("plotly.js did not load")); };
        document.head.appendChild(tag);
      });
    }
    return plotlyLoaded;
  }
  function calibrationInputs() {
    var inputs = $("cal-kind").selectedOptions[0].dataset.inputs.split(" ");
    ["log", "readings", "six", "points"].forEach(function (name) {
      document.querySelectorAll(".cal-" + name).forEach(function (row) { row.hidden = inputs.indexOf(name) < 0; });
    });
    $("cal-accept").disabled = true;
  }
  $("cal-kind").addEventListener("change", calibrationInputs);
  $("cal-fit").addEventListener("click", function () {
    showError(""); $("cal-accept").disabled = true;
    var inputs = $("cal-kind").selectedOptions[0].dataset.inputs.split(" ");
    var body = { kind: $("cal-kind").value };
    if (inputs.indexOf("log") >= 0) { body.file = $("cal-file").value; body.format = $("cal-format").value; body.rate_hz = number($("cal-rate")); }
    if (inputs.indexOf("readings") >= 0) { body.readings = $("cal-readings").value; }
    if (inputs.indexOf("six") >= 0) { body.six_point = $("cal-six").checked; }
    if (inputs.indexOf("points") >= 0) { body.points = $("cal-points").value; }
    Promise.all([api("POST", "api/calibrate", body), withPlotly()]).then(function (both) {
      var j = both[0];
      calibration = j;
      $("cal-lines").textContent = j.lines.join("\n"); $("cal-lines").hidden = false;
      var names = j.labels.length ? j.labels : j.residuals_mm.map(function (r, k) { return k; });
      var kept = [], rejected = [];
      j.residuals_mm.forEach(function (r, k) { (j.rejected.indexOf(k) >= 0 ? rejected : kept).push([names[k], r]); });
      var first = function (p) { return p[0]; }, second = function (p) { return p[1]; };
      var many = !j.labels.length;
      Plotly.react($("cal-plot"), [
        { type: "scatter", mode: "markers", name: "kept", x: kept.map(first), y: kept.map(second), marker: { size: many ? 3 : 8 } },
        { type: "scatter", mode: "markers", name: "rejected", x: rejected.map(first), y: rejected.map(second), marker: { size: many ? 6 : 10, color: "#c0392b" } }
      ], { height: 220, margin: { l: 50, r: 10, t: 10, b: 40 }, xaxis: { title: { text: many ? "sample" : "point" }, type: many ? "linear" : "category", categoryorder: "array", categoryarray: many ? [] : names },
        yaxis: { title: { text: "residual [mm]" } } }, CONFIG);
      $("cal-accept").textContent = "Accept into the problem (" + j.key + ")";
      $("cal-accept").disabled = false;
    }).catch(function (e) { showError(e.message); });
  });
  $("cal-accept").addEventListener("click", function () { if (calibration) { send(calibration.change); $("cal-accept").disabled = true; } });

  function fillValues(v) {
    values = v;
    document.querySelectorAll("input.scalar").forEach(function (i) {
      if (document.activeElement !== i) { var x = v.scalars[i.dataset.key]; i.value = x === null ? "" : String(x); }
    });
    document.querySelectorAll(".pose input").forEach(function (i) {
      if (document.activeElement !== i) { i.value = String(v.poses[i.dataset.key][i.dataset.part][Number(i.dataset.axis)]); }
    });
    document.querySelectorAll("input.move").forEach(function (i) {
      if (document.activeElement === i) { return; }
      var x = v.move[i.dataset.part][Number(i.dataset.axis)];
      i.value = String(i.dataset.part === "xyz" ? Math.round(x * 1000) : Math.round(x));
      $(i.id + "-value").textContent = i.value;
    });
    showFrames();
  }

  // ---- the 3D view and the gizmo --------------------------------------------------------------
  var slider = $("frame"), view = new View($("scene"), dragged), lastSent = 0, dragTimer = null;
  $("scene").view = view;   // for a browser test to find the gizmo's handles
  var DRAG_MS = 120;   // the least time between two changes sent while a frame is dragged [ms]
  function frameIndex() { return Math.min(Number(slider.value), scene.robot.frames.length - 1); }
  function tcpWorld(f) { return rowMatrix(scene.robot.flange[f]).multiply(poseMatrix(values.poses["tool.tcp_in_flange"])); }
  function showFrames() {   // the frames the gizmo may drag, drawn as axes
    if (!values) { return; }
    var frames = {};
    ["frames.cad_in_world", "frames.source_in_world", "robot.base_in_world"].forEach(function (k) { frames[k] = poseMatrix(values.poses[k]); });
    frames.move = frames["frames.cad_in_world"];
    if (scene && scene.robot && scene.robot.flange) { frames["tool.tcp_in_flange"] = tcpWorld(frameIndex()); }
    view.setFrames(frames);
  }
  function dragChange(target, m) {   // the change a frame dragged to pose ``m`` (in {F}) asks for
    var c = {};
    if (target === "tool.tcp_in_flange") {
      c[target] = matrixPose(rowMatrix(scene.robot.flange[frameIndex()]).invert().multiply(m));
    } else if (target === "move") {   // the workpiece: a move about the CAD origin as placed
      var mv = values.move, cad = poseMatrix(values.poses["frames.cad_in_world"]);
      var o = new (cad.constructor)().makeTranslation(cad.elements[12] - mv.xyz[0], cad.elements[13] - mv.xyz[1], cad.elements[14] - mv.xyz[2]);
      var oi = o.clone().invert(), d = o.clone().multiply(poseMatrix(mv)).multiply(oi);
      var placed = d.invert().multiply(cad);
      c.move = matrixPose(oi.multiply(m.clone().multiply(placed.invert())).multiply(o));
    } else {
      c[target] = matrixPose(m);
    }
    return c;
  }
  function dragged(target, m, done) {   // while dragging, a change at most every DRAG_MS; the last on release
    var now = Date.now();
    clearTimeout(dragTimer);
    if (done || now - lastSent >= DRAG_MS) { lastSent = now; send(dragChange(target, m)); return; }
    dragTimer = setTimeout(function () { lastSent = Date.now(); send(dragChange(target, m)); }, DRAG_MS);
  }
  function attachGizmo() { view.attach($("gizmo").value || null, $("gizmo-mode").value, $("gizmo").value === "move"); }
  $("gizmo").addEventListener("change", attachGizmo);
  $("gizmo-mode").addEventListener("change", attachGizmo);
  function colourBar(result) {
    $("quantity-note").textContent = result.note ? "(" + result.note + ")" : "";
    var bar = $("colour-bar");
    bar.hidden = !result.range;
    if (result.range) { $("colour-lo").textContent = result.range.lo.toFixed(2); $("colour-hi").textContent = result.range.hi.toFixed(2); }
  }
  function draw(sections) {
    if (!scene || !scene.parts || !scene.robot) { return; }
    if (sections.indexOf("cell") >= 0) { view.setCell(scene.cell); }
    if (sections.indexOf("parts") >= 0) {
      view.setParts(scene.parts);
      var visual = scene.parts.some(function (p) { return p.kind === "visual"; });
      $("show-collision").disabled = !visual;
      $("collision-toggle").hidden = !visual;   // no visual meshes: the collision shapes are all there is
      if (!visual) { $("show-collision").checked = true; }
    }
    if (sections.indexOf("robot") >= 0) { $("visual-note").textContent = scene.robot.visual_note || ""; }
    if (sections.indexOf("paths") >= 0) { colourBar(view.setPaths(scene.paths, $("quantity").value)); }
    if (sections.indexOf("motions") >= 0) { view.setMotions(scene.motions || []); listMotions(); }
    if (sections.indexOf("demo") >= 0) { view.setDemo(scene.demo || {}); }
    ["recorded", "aligned", "motions", "collision"].forEach(function (k) { view.showLayer(k, $("show-" + k).checked); });
    showFrame();
    view.fit();
    $("scene").dataset.objects = JSON.stringify(view.names());
    document.body.dataset.scene = String(scene.revision);
  }
  function showFrame() {
    if (!scene || !scene.robot) { return; }
    var f = frameIndex();
    view.showRobot(scene.robot.frames[f]);
    $("frame-label").textContent = scene.robot.labels[f];
    showFrames();
  }
  slider.addEventListener("input", showFrame);
  ["recorded", "aligned", "motions", "collision"].forEach(function (k) {
    $("show-" + k).addEventListener("change", function () { view.showLayer(k, $("show-" + k).checked); });
  });
  var selectedMotion = null;   // the name of the motion selected in the list (kept over re-solves)
  function listMotions() {   // the planned motions, each a button: a click selects it in the 3D view
    var ul = $("motions"), motions = scene.motions || [];
    ul.textContent = "";
    var n = motions.findIndex(function (m) { return m.name === selectedMotion; });
    motions.forEach(function (m, k) {
      var li = document.createElement("li");
      li.dataset.index = String(k); li.className = "motion st-" + m.status + (k === n ? " selected" : "");
      li.textContent = m.name + " (" + m.kind + ", " + m.status + ")";
      li.addEventListener("click", function () { selectedMotion = k === n ? null : m.name; listMotions(); });
      ul.appendChild(li);
    });
    $("motion-figures").textContent = n >= 0 ? motions[n].figures.join("\n") : "";
    $("motion-figures").hidden = n < 0;
    $("motions-none").hidden = motions.length > 0;
    view.select(n >= 0 ? n : null);
  }
  view.onHover = function (hit, x, y) {   // the waypoint under the pointer: its index and figures
    var box = $("hover");
    if (!hit || !scene) { box.hidden = true; delete box.dataset.index; return; }
    var path = scene.paths[hit.path], q = path.quantities, lines = [path.name + ", waypoint " + hit.index];
    [["deviation", "deviation", "deg", 2], ["clearance", "clearance", "mm", 1], ["speed", "speed", "mm/s", 1], ["slack", "repair slack", "deg", 2]].forEach(function (row) {
      var e = q[row[0]], v = e && e.values ? e.values[hit.index] : null;
      lines.push(row[1] + " " + (v === null || v === undefined ? "-" : v.toFixed(row[3]) + " " + row[2]));
    });
    box.textContent = lines.join("\n");
    box.dataset.index = String(hit.index);
    var r = $("scene").getBoundingClientRect();
    box.style.left = (x - r.left + 12) + "px"; box.style.top = (y - r.top + 12) + "px";
    box.hidden = false;
  };
  $("quantity").addEventListener("change", function () { if (scene) { colourBar(view.setPaths(scene.paths, $("quantity").value)); } });
  var timer = null;
  $("play").addEventListener("click", function () {
    if (timer) { clearInterval(timer); timer = null; $("play").textContent = "Play"; return; }
    $("play").textContent = "Pause";
    timer = setInterval(function () {
      slider.value = String((Number(slider.value) + 1) % (Number(slider.max) + 1)); showFrame();
    }, 100);
  });

  // ---- the states from the server -------------------------------------------------------------
  function highlightSegments() {
    document.querySelectorAll("#verdict ul.segments li").forEach(function (li, n) {
      li.title = "show on the path";
      li.addEventListener("click", function () {
        var m = /waypoints (\d+)-(\d+)/.exec(li.textContent);
        if (!m || !scene) { return; }
        var frames = scene.robot.where, best = 0;
        frames.forEach(function (w, k) { if (Math.abs(w[1] - Number(m[1])) < Math.abs(frames[best][1] - Number(m[1]))) { best = k; } });
        slider.value = String(best); showFrame();
      });
    });
  }
  function onMessage(msg) {
    if (msg.type === "error") { showError(msg.message); return; }
    if (msg.type === "pending") {
      $("state").textContent = "solving revision " + msg.revision + "...";
      $("state").className = "busy"; fillValues(msg.values);
      document.body.dataset.latest = String(Math.max(Number(document.body.dataset.latest || 0), msg.revision));
      return;
    }
    if (msg.type === "verdict") {
      if (msg.error) { showError(msg.error); }
      if (msg.verdict_html) { $("verdict-box").innerHTML = msg.verdict_html; highlightSegments(); }
      if (msg.verdict_html) { $("demo-quality").innerHTML = msg.demo_quality_html || ""; $("demo-quality").hidden = !msg.demo_quality_html; }
      fillValues(msg.values);
      var busy = msg.latest !== msg.revision;
      $("state").textContent = "verdict of revision " + msg.revision + " in " + msg.latency_s.toFixed(2) + " s" +
        (busy ? "; solving revision " + msg.latest + "..." : "");
      $("state").className = busy ? "busy" : "";
      document.body.dataset.status = msg.status || "";
      document.body.dataset.revision = String(msg.revision);
      document.body.dataset.latest = String(Math.max(Number(document.body.dataset.latest || 0), msg.latest));
      return;
    }
    if (msg.type === "scene") {
      scene = Object.assign(scene || {}, msg.scene); scene.revision = msg.revision;   // the sections that changed
      slider.max = String(scene.robot.frames.length - 1);
      draw(Object.keys(msg.scene));
    }
  }
  var proto = window.location.protocol === "https:" ? "wss://" : "ws://";
  var base = window.location.pathname.replace(/[^/]*$/, "");
  socket = new WebSocket(proto + window.location.host + base + url("ws"));
  socket.onmessage = function (ev) {
    var msg = JSON.parse(ev.data);
    if (msg.type === "scene" && !document.body.dataset.firstSceneBytes) { document.body.dataset.firstSceneBytes = String(ev.data.length); }
    onMessage(msg);
    if (msg.type === "scene" && !document.body.dataset.firstSceneMs) { document.body.dataset.firstSceneMs = String(Math.round(performance.now())); }
  };
  socket.onclose = function () { $("state").textContent = "the server closed the connection"; $("state").className = "busy"; };
}
