// report.html: draws the 3D view and the panels from the JSON in #report-data with Plotly.
// Marks every plot it drew with data-rendered="1" and the page with data-render-ms (time since
// navigation start when everything was drawn), so a headless browser can check the page.
(function () {
  "use strict";
  document.body.dataset.scriptStartMs = String(Math.round(performance.now()));  // Plotly parsed by now
  if (window.location.hash === "#scene-only") { document.body.classList.add("scene-only"); }
  var DATA = JSON.parse(document.getElementById("report-data").textContent);
  var CONFIG = { responsive: true, displaylogo: false };
  var pending = [];

  // ---- 3D view ---------------------------------------------------------------------------------
  var sceneDiv = document.getElementById("scene");
  var traces = [];
  var robotIdx = [];
  var pathIdx = [];
  var robot = DATA.scene.robot;

  DATA.scene.cell.forEach(function (o) {
    traces.push({
      type: "mesh3d", name: o.name, x: o.x, y: o.y, z: o.z, i: o.i, j: o.j, k: o.k,
      color: o.kind === "workpiece" ? "#7fb3d5" : "#b0b0b0", opacity: o.kind === "workpiece" ? 0.7 : 0.45,
      flatshading: true, hoverinfo: "name", showlegend: true, legendgroup: "cell"
    });
  });

  function place(part, m) {
    // m: 3x4 row-major pose of the part in the world; returns the moved vertices
    var n = part.x.length, x = new Array(n), y = new Array(n), z = new Array(n);
    for (var a = 0; a < n; a++) {
      var px = part.x[a], py = part.y[a], pz = part.z[a];
      x[a] = m[0] * px + m[1] * py + m[2] * pz + m[3];
      y[a] = m[4] * px + m[5] * py + m[6] * pz + m[7];
      z[a] = m[8] * px + m[9] * py + m[10] * pz + m[11];
    }
    return [x, y, z];
  }

  robot.parts.forEach(function (part, p) {
    var v = place(part, robot.frames[0][p]);
    robotIdx.push(traces.length);
    traces.push({
      type: "mesh3d", name: p === 0 ? "robot" : part.name, x: v[0], y: v[1], z: v[2],
      i: part.i, j: part.j, k: part.k, color: part.kind === "tool" ? "#505050" : "#f39c12",
      opacity: 1.0, flatshading: true, hoverinfo: "name", hovertext: part.name,
      showlegend: p === 0, legendgroup: "robot"
    });
  });

  var quantitySelect = document.getElementById("quantity");
  var quantity = quantitySelect.value;

  function colouring(path, q) {
    var entry = path.quantities[q];
    if (!entry || entry.missing) { return null; }
    return entry.values;
  }

  DATA.scene.paths.forEach(function (path, i) {
    var values = colouring(path, quantity);
    pathIdx.push(traces.length);
    traces.push({
      type: "scatter3d", mode: "lines", name: path.name + " (" + path.status + ")",
      x: path.x, y: path.y, z: path.z,
      line: {
        width: 7, color: values || "#1f77b4", colorscale: "Viridis",
        showscale: i === 0 && values !== null,
        colorbar: { title: { text: path.quantities[quantity].title }, len: 0.6 }
      },
      text: path.s.map(function (s) { return "s = " + s.toFixed(3) + " m"; }),
      hoverinfo: "text+name", showlegend: false
    });
    traces.push({
      type: "scatter3d", mode: "lines", name: "tool axis", x: path.axis.x, y: path.axis.y, z: path.axis.z,
      line: { width: 2, color: "#555555" }, showlegend: i === 0, legendgroup: "axis", hoverinfo: "skip"
    });
    path.marks.forEach(function (mark) {
      traces.push({
        type: "scatter3d", mode: "markers", name: mark.label,
        x: mark.index.map(function (k) { return path.x[k]; }),
        y: mark.index.map(function (k) { return path.y[k]; }),
        z: mark.index.map(function (k) { return path.z[k]; }),
        marker: { size: 4, color: mark.kind === "infeasible" ? "#e74c3c" : "#e67e22" }
      });
    });
  });

  var layout3d = {
    margin: { l: 0, r: 0, t: 0, b: 0 }, uirevision: "keep",
    height: document.body.classList.contains("scene-only") ? Math.max(500, window.innerHeight - 90) : 640,
    legend: { x: 0, y: 1, bgcolor: "rgba(255,255,255,0.7)" },
    scene: {
      aspectmode: "data",
      xaxis: { title: { text: "x [m]" } }, yaxis: { title: { text: "y [m]" } }, zaxis: { title: { text: "z [m]" } },
      camera: { eye: { x: 1.4, y: -1.6, z: 1.0 } }
    }
  };
  pending.push(Plotly.newPlot(sceneDiv, traces, layout3d, CONFIG).then(function () {
    sceneDiv.dataset.rendered = "1";
    document.body.dataset.sceneMs = String(Math.round(performance.now()));
    sceneDiv.dataset.traces = String(traces.length);
  }));

  var slider = document.getElementById("frame");
  var frameLabel = document.getElementById("frame-label");
  slider.max = String(robot.frames.length - 1);
  function showFrame(f) {
    var xs = [], ys = [], zs = [];
    robot.parts.forEach(function (part, p) {
      var v = place(part, robot.frames[f][p]);
      xs.push(v[0]); ys.push(v[1]); zs.push(v[2]);
    });
    frameLabel.textContent = robot.labels[f];
    return Plotly.restyle(sceneDiv, { x: xs, y: ys, z: zs }, robotIdx);
  }
  frameLabel.textContent = robot.labels[0];
  slider.addEventListener("input", function () { showFrame(Number(slider.value)); });
  var timer = null;
  var play = document.getElementById("play");
  play.addEventListener("click", function () {
    if (timer !== null) { clearInterval(timer); timer = null; play.textContent = "Play"; return; }
    play.textContent = "Pause";
    timer = setInterval(function () {
      var f = (Number(slider.value) + 1) % robot.frames.length;
      slider.value = String(f);
      showFrame(f);
    }, 120);
  });
  quantitySelect.addEventListener("change", function () {
    quantity = quantitySelect.value;
    DATA.scene.paths.forEach(function (path, i) {
      var values = colouring(path, quantity);
      Plotly.restyle(sceneDiv, {
        "line.color": [values || "#1f77b4"], "line.showscale": [i === 0 && values !== null],
        "line.colorbar.title.text": [path.quantities[quantity].title]
      }, [pathIdx[i]]);
    });
    var missing = DATA.scene.paths[0].quantities[quantity].missing;
    document.getElementById("quantity-note").textContent = missing ? "(" + missing + ")" : "";
  });

  // ---- panels ------------------------------------------------------------------------------------
  var passSelect = document.getElementById("pass");

  function panelTraces(entry) {
    return entry.lines.map(function (l) {
      var trace = {
        type: "scatter", mode: l.mode || "lines", name: l.name, x: l.x, y: l.y,
        line: { color: l.colour, dash: l.dash || "solid", width: l.dash ? 1.5 : 2 },
        marker: { color: l.colour, size: 4, symbol: l.symbol || "circle" }, showlegend: l.legend !== false,
        legendgroup: l.group || l.name
      };
      if (l.text) {  // per point: whether the figure is measured or a lower bound
        trace.text = l.text;
        trace.hovertemplate = "%{y}<br>%{text}<extra>%{fullData.name}</extra>";
      }
      return trace;
    });
  }

  function renderPass(i) {
    var pass = DATA.panels.passes[i];
    return Promise.all(DATA.panels.titles.map(function (t) {
      var id = t[0], title = t[1];
      var div = document.getElementById("panel-" + id);
      var entry = pass.panels[id];
      var layout = {
        title: { text: title, x: 0.01, xanchor: "left" }, height: 330,
        margin: { l: 60, r: 10, t: 40, b: 45 }, xaxis: { title: { text: "arc length s [m]" } },
        legend: { orientation: "v", x: 1.01, y: 1 }
      };
      var data = [];
      if (entry.empty) {
        layout.xaxis = { visible: false };
        layout.yaxis = { visible: false };
        layout.annotations = [{ text: entry.empty, showarrow: false, xref: "paper", yref: "paper",
                                x: 0.5, y: 0.5, font: { size: 15, color: "#666666" } }];
        div.dataset.empty = entry.empty;
      } else {
        data = panelTraces(entry);
        delete div.dataset.empty;
      }
      return Plotly.react(div, data, layout, CONFIG).then(function () {
        div.dataset.rendered = "1";
        div.dataset.traces = String(data.length);
      });
    }));
  }

  if (passSelect) {
    passSelect.addEventListener("change", function () { renderPass(Number(passSelect.value)); });
  }
  pending.push(renderPass(0));

  Promise.all(pending).then(function () {
    document.body.dataset.renderMs = String(Math.round(performance.now()));
    document.body.dataset.rendered = "1";
  });
})();
