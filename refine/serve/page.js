// refine serve: shows the states the server sends over the websocket and sends the changes.
// The body's data-revision is the revision of the verdict shown, data-status its status and
// data-scene the revision of the scene drawn, so a browser test can wait for them.
(function () {
  "use strict";
  var params = new URLSearchParams(window.location.search);
  var token = params.get("token") || "";
  var CONFIG = { responsive: true, displaylogo: false };
  var $ = function (id) { return document.getElementById(id); };
  var parts = null;       // the robot's shapes in their own frames
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
  function moveValue() {
    var move = { xyz: [0, 0, 0], rpy_deg: [0, 0, 0] };
    document.querySelectorAll("input.move").forEach(function (i) {
      var v = Number(i.value);
      move[i.dataset.part][Number(i.dataset.axis)] = i.dataset.part === "xyz" ? v / 1000 : v;
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

  var calibration = null;
  $("cal-fit").addEventListener("click", function () {
    showError(""); $("cal-accept").disabled = true;
    api("POST", "api/calibrate", { kind: "pivot", file: $("cal-file").value, format: $("cal-format").value,
      rate_hz: Number($("cal-rate").value) }).then(function (j) {
      calibration = j;
      $("cal-lines").textContent = j.lines.join("\n"); $("cal-lines").hidden = false;
      var kept = [], rejected = [];
      j.residuals_mm.forEach(function (r, k) { (j.rejected.indexOf(k) >= 0 ? rejected : kept).push([k, r]); });
      Plotly.react($("cal-plot"), [
        { type: "scatter", mode: "markers", name: "kept", x: kept.map(function (p) { return p[0]; }), y: kept.map(function (p) { return p[1]; }), marker: { size: 3 } },
        { type: "scatter", mode: "markers", name: "rejected", x: rejected.map(function (p) { return p[0]; }), y: rejected.map(function (p) { return p[1]; }), marker: { size: 6, color: "#c0392b" } }
      ], { height: 220, margin: { l: 50, r: 10, t: 10, b: 40 }, xaxis: { title: { text: "sample" } }, yaxis: { title: { text: "residual [mm]" } } }, CONFIG);
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
  }

  // ---- the 3D view ----------------------------------------------------------------------------
  var sceneDiv = $("scene"), slider = $("frame"), robotIdx = [];
  function place(part, m) {
    var n = part.x.length, x = new Array(n), y = new Array(n), z = new Array(n);
    for (var a = 0; a < n; a++) {
      var px = part.x[a], py = part.y[a], pz = part.z[a];
      x[a] = m[0] * px + m[1] * py + m[2] * pz + m[3];
      y[a] = m[4] * px + m[5] * py + m[6] * pz + m[7];
      z[a] = m[8] * px + m[9] * py + m[10] * pz + m[11];
    }
    return [x, y, z];
  }
  function draw() {
    if (!scene || !parts) { return; }
    var traces = [], q = $("quantity").value, f = Math.min(Number(slider.value), scene.robot.frames.length - 1);
    scene.cell.forEach(function (o) {
      traces.push({ type: "mesh3d", name: o.name, x: o.x, y: o.y, z: o.z, i: o.i, j: o.j, k: o.k,
        color: o.kind === "workpiece" ? "#7fb3d5" : "#b0b0b0", opacity: o.kind === "workpiece" ? 0.7 : 0.45,
        flatshading: true, hoverinfo: "name", showlegend: true, legendgroup: "cell" });
    });
    robotIdx = [];
    parts.forEach(function (part, p) {
      var v = place(part, scene.robot.frames[f][p]);
      robotIdx.push(traces.length);
      traces.push({ type: "mesh3d", name: p === 0 ? "robot" : part.name, x: v[0], y: v[1], z: v[2],
        i: part.i, j: part.j, k: part.k, color: part.kind === "tool" ? "#505050" : "#f39c12", opacity: 1.0,
        flatshading: true, hoverinfo: "name", hovertext: part.name, showlegend: p === 0, legendgroup: "robot" });
    });
    var note = "";
    scene.paths.forEach(function (path, i) {
      var entry = path.quantities[q], colours = entry && !entry.missing ? entry.values : null;
      if (!colours && entry) { note = entry.missing; }
      traces.push({ type: "scatter3d", mode: "lines", name: path.name + " (" + path.status + ")",
        x: path.x, y: path.y, z: path.z,
        line: { width: 7, color: colours || "#1f77b4", colorscale: "Viridis", showscale: i === 0 && colours !== null,
          colorbar: { title: { text: entry ? entry.title : "" }, len: 0.6 } },
        text: path.s.map(function (s) { return "s = " + s.toFixed(3) + " m"; }), hoverinfo: "text+name", showlegend: false });
      traces.push({ type: "scatter3d", mode: "lines", name: "tool axis", x: path.axis.x, y: path.axis.y, z: path.axis.z,
        line: { width: 2, color: "#555555" }, showlegend: i === 0, legendgroup: "axis", hoverinfo: "skip" });
      path.marks.forEach(function (mark) {
        traces.push({ type: "scatter3d", mode: "markers", name: mark.label,
          x: mark.index.map(function (k) { return path.x[k]; }), y: mark.index.map(function (k) { return path.y[k]; }),
          z: mark.index.map(function (k) { return path.z[k]; }),
          marker: { size: 4, color: mark.kind === "infeasible" ? "#e74c3c" : "#e67e22" } });
      });
    });
    $("quantity-note").textContent = note ? "(" + note + ")" : "";
    var layout = { margin: { l: 0, r: 0, t: 0, b: 0 }, uirevision: "keep",
      legend: { x: 0, y: 1, bgcolor: "rgba(255,255,255,0.7)" },
      scene: { aspectmode: "data", xaxis: { title: { text: "x [m]" } }, yaxis: { title: { text: "y [m]" } },
        zaxis: { title: { text: "z [m]" } }, camera: { eye: { x: 1.4, y: -1.6, z: 1.0 } } } };
    var rev = scene.revision;
    return Plotly.react(sceneDiv, traces, layout, CONFIG).then(function () { document.body.dataset.scene = String(rev); });
  }
  function showFrame() {
    if (!scene || !parts) { return; }
    var f = Math.min(Number(slider.value), scene.robot.frames.length - 1), xs = [], ys = [], zs = [];
    parts.forEach(function (part, p) { var v = place(part, scene.robot.frames[f][p]); xs.push(v[0]); ys.push(v[1]); zs.push(v[2]); });
    $("frame-label").textContent = scene.robot.labels[f];
    return Plotly.restyle(sceneDiv, { x: xs, y: ys, z: zs }, robotIdx);
  }
  slider.addEventListener("input", showFrame);
  $("quantity").addEventListener("change", draw);
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
      scene = Object.assign(scene || {}, msg.scene); scene.revision = msg.revision; parts = scene.parts;   // the sections that changed
      slider.max = String(scene.robot.frames.length - 1);
      $("frame-label").textContent = scene.robot.labels[Math.min(Number(slider.value), scene.robot.frames.length - 1)];
      draw();
    }
  }
  var proto = window.location.protocol === "https:" ? "wss://" : "ws://";
  var base = window.location.pathname.replace(/[^/]*$/, "");
  socket = new WebSocket(proto + window.location.host + base + url("ws"));
  socket.onmessage = function (ev) { onMessage(JSON.parse(ev.data)); };
  socket.onclose = function () { $("state").textContent = "the server closed the connection"; $("state").className = "busy"; };
})();
