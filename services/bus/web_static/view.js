// vrsim live view: one page, plain JavaScript and canvas, everything from this server (no network).
// Data: GET /api/view (role, CSRF token, map geometry, colour scale), GET /api/map.png (the
// prescription), /events (Server-Sent Events: `hello` = everything, then `frame` = what changed, at most
// 20 a second, read through fetch so that it carries the key). The session is two halves: an HttpOnly
// cookie, which the browser sends by itself (to every port of this host: another local server can be
// lured into receiving it), and this page's key, which only this origin's script holds (localStorage is
// per scheme, host and port) and sends in X-Vrsim-Key with every request here. A login's redirect brings
// a new key in the URL's fragment (no server sees a fragment), taken out of the address bar at once.
// Without a session (401) the page goes to /login. State for scripts and tests: window.vrsimView.
"use strict";
(() => {
  const HISTORY = 600; // chart points shown (30 s of frames at 20 a second)
  const TRAIL = 400; // recent true positions drawn behind the tractor
  const $ = (id) => document.getElementById(id);

  const S = (window.vrsimView = {
    connected: false, events: 0, hellos: 0, frames: 0, runId: "", role: "viewer",
    pose: null, shaft: null, rate: null, status: null, report: null, catchup: null,
    tractorMoves: 0, appliedCells: 0, points: 0, mapVersion: null, mapLoaded: false, draws: 0,
    mapShown: null, // the map version whose prescription the canvas shows (null: none yet)
    run: {}, reportPartial: null, realtime: null,
  });

  let view = null; // /api/view
  let mapImg = null; // the prescription PNG
  let mapImgVersion = null; // the map version mapImg is of
  let grid = null; // view grid: west_m, north_m, cell_x_m, cell_y_m, rows, cols
  let values = null; // Float32Array rows*cols of applied kg/ha (NaN: not yet)
  let layer = null; // offscreen canvas of the applied layer, one pixel per cell
  let layerImg = null;
  let pending = []; // applied deltas that came before the grid
  let run = {};
  let points = [];
  let trail = [];
  let viewRequests = 0;
  let csrf = ""; // the session's CSRF token (from /api/view), sent with every POST
  let dirty = true;

  // ------------------------------------------------------------------ the session's key
  const KEY_ITEM = "vrsim_key";
  const keys = []; // to try, best first: the one a login just gave, then the one kept
  const fresh = /^#key=([A-Za-z0-9_-]+)$/.exec(window.location.hash);
  if (window.location.hash) history.replaceState(null, "", window.location.pathname + window.location.search);
  if (fresh) keys.push(fresh[1]);
  const kept = stored();
  if (kept && kept !== keys[0]) keys.push(kept);
  const withKey = (headers = {}) => ({ ...headers, "X-Vrsim-Key": keys[0] || "" });
  const toLogin = () => window.location.assign("/login");

  function stored(value) {
    try {
      if (value === undefined) return window.localStorage.getItem(KEY_ITEM);
      window.localStorage.setItem(KEY_ITEM, value);
    } catch (e) { /* storage refused (a private window's settings): the key lives as long as the page */ }
    return null;
  }

  // The first key /api/view takes is kept (a fragment another page put in the URL cannot replace a good
  // one); none: log in again.
  async function pickKey() {
    while (keys.length) {
      const r = await fetch("/api/view", { headers: withKey() });
      if (r.status !== 401) { stored(keys[0]); return true; }
      keys.shift();
    }
    toLogin();
    return false;
  }

  // ------------------------------------------------------------------ events
  async function stream() {
    for (;;) {
      try {
        const r = await fetch("/events", { headers: withKey({ Accept: "text/event-stream" }), cache: "no-store" });
        if (r.status === 401) return toLogin();
        if (r.ok) {
          setConn(true);
          const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
          let buf = "";
          for (;;) {
            const { value, done } = await reader.read();
            if (done) break;
            buf += value;
            for (let end; (end = buf.indexOf("\n\n")) >= 0; buf = buf.slice(end + 2)) onEvent(buf.slice(0, end));
          }
        }
      } catch (e) { /* the connection broke: again below, as EventSource would */ }
      setConn(false);
      await new Promise((again) => setTimeout(again, 1000));
    }
  }

  function onEvent(block) {
    let kind = "", data = "";
    for (const line of block.split("\n")) {
      if (line.startsWith("event: ")) kind = line.slice(7);
      else if (line.startsWith("data: ")) data += line.slice(6);
    }
    if (kind === "hello" || kind === "frame") onDoc(JSON.parse(data), kind === "hello"); // else a keepalive
  }

  function setConn(on) {
    S.connected = on;
    $("conn").textContent = on ? "live" : "reconnecting";
    $("conn").className = on ? "conn live" : "conn";
  }

  function onDoc(doc, hello) {
    S.events++;
    if (hello) {
      S.hellos++;
      run = doc.run || {};
      S.run = run;
      S.runId = doc.run_id;
      S.catchup = doc.catchup;
      points = [];
      trail = [];
      clearApplied();
      if (doc.map_version !== S.mapVersion) loadView(doc.map_version);
      $("rateUnit").textContent = rateUnit()[0];
    } else {
      S.frames++;
    }
    if (doc.pose) {
      const p = doc.pose;
      if (!S.pose || p.x_m !== S.pose.x_m || p.y_m !== S.pose.y_m) S.tractorMoves++;
      S.pose = p;
      trail.push([p.x_m, p.y_m]);
      if (trail.length > TRAIL) trail.splice(0, trail.length - TRAIL);
    }
    if (doc.shaft) S.shaft = doc.shaft;
    if (doc.rate) S.rate = doc.rate;
    for (const pt of doc.points) points.push(pt);
    if (points.length > HISTORY) points.splice(0, points.length - HISTORY);
    S.points = points.length;
    applyCells(doc.applied);
    if (doc.status) { S.status = doc.status; showStatus(doc.status); }
    if (doc.report) { S.report = doc.report; showReport(doc.report); }
    if (hello) showCatchup();
    $("run").textContent = S.runId ? `${S.runId}${run.scenario ? " · " + run.scenario : ""}` : "no run yet";
    dirty = true;
  }

  // ------------------------------------------------------------------ map and layers
  function loadView(version) {
    S.mapVersion = version;
    values = null; // deltas wait in `pending` until the new grid is there
    const request = ++viewRequests;
    fetch("/api/view", { headers: withKey() }).then((r) => {
      if (r.status === 401) toLogin();
      return r.json();
    }).then((doc) => {
      if (request !== viewRequests) return; // a later request is on its way: its answer counts
      view = doc;
      S.role = doc.role;
      csrf = doc.csrf;
      $("ops").hidden = doc.role !== "operator";
      if (!doc.map) return;
      grid = doc.map.grid;
      S.mapVersion = doc.map.version;
      if (mapImgVersion !== doc.map.version) { mapImg = null; mapImgVersion = null; S.mapLoaded = false; }
      values = new Float32Array(grid.rows * grid.cols).fill(NaN);
      layer = document.createElement("canvas");
      layer.width = grid.cols;
      layer.height = grid.rows;
      layerImg = layer.getContext("2d").createImageData(grid.cols, grid.rows);
      for (const d of pending.splice(0)) applyCells(d);
      S.appliedCells = countCells();
      drawLegend(doc.map.scale);
      const info = doc.map.info;
      $("mapinfo").textContent = `${info.source} · ${info.crs} · ${grid.cols}×${grid.rows} cells of ` +
        `${grid.cell_x_m.toFixed(1)} m`;
      // Fetched with the key (an <img src> could not send it), decoded without a URL of its own.
      const version = doc.map.version;
      fetch(doc.map.png, { headers: withKey() }).then((r) => (r.ok ? r.blob() : Promise.reject(r.status)))
        .then((blob) => createImageBitmap(blob))
        .then((bitmap) => {
          if (request !== viewRequests) return; // a newer map is on its way
          mapImg = bitmap; mapImgVersion = version; S.mapLoaded = true; dirty = true;
        })
        .catch(() => {});
      dirty = true;
    }).catch(() => { if (request === viewRequests) S.mapVersion = null; });
  }

  function clearApplied() {
    pending = [];
    if (values) values.fill(NaN);
    if (layerImg) {
      layerImg.data.fill(0);
      layer.getContext("2d").clearRect(0, 0, layer.width, layer.height);
    }
    S.appliedCells = 0;
  }

  // For scripts and tests: the cells the applied layer's canvas really shows.
  S.layerPixels = () => {
    if (!layer) return 0;
    const px = layer.getContext("2d").getImageData(0, 0, layer.width, layer.height).data;
    let n = 0;
    for (let i = 3; i < px.length; i += 4) if (px[i] > 0) n++;
    return n;
  };

  function applyCells(d) {
    if (!d || !d.i.length) return;
    if (!values) { pending.push(d); return; }
    const lut = view.map.scale.lut, lo = view.map.scale.vmin_kg_ha, hi = view.map.scale.vmax_kg_ha;
    const px = layerImg.data, cols = grid.cols;
    let r0 = Infinity, r1 = -1, c0 = Infinity, c1 = -1; // the changed rectangle, put back alone
    for (let k = 0; k < d.i.length; k++) {
      const i = d.i[k], v = d.v[k];
      if (i < 0 || i >= values.length) continue;
      const r = Math.floor(i / cols), col = i - r * cols;
      r0 = Math.min(r0, r); r1 = Math.max(r1, r); c0 = Math.min(c0, col); c1 = Math.max(c1, col);
      if (Number.isNaN(values[i])) S.appliedCells++;
      values[i] = v;
      const c = lut[Math.max(0, Math.min(lut.length - 1, Math.round((v - lo) / (hi - lo) * (lut.length - 1))))];
      px[4 * i] = c[0]; px[4 * i + 1] = c[1]; px[4 * i + 2] = c[2]; px[4 * i + 3] = 255;
    }
    if (r1 >= 0) layer.getContext("2d").putImageData(layerImg, 0, 0, c0, r0, c1 - c0 + 1, r1 - r0 + 1);
  }

  function countCells() {
    let n = 0;
    for (let i = 0; i < values.length; i++) if (!Number.isNaN(values[i])) n++;
    return n;
  }

  function drawLegend(scale) {
    const c = $("legend").getContext("2d");
    scale.lut.forEach((rgb, i) => { c.fillStyle = `rgb(${rgb})`; c.fillRect(i, 0, 1, 12); });
    // The legend in the map's own unit (the colours are painted from the kg/ha range).
    const digits = (v) => (Math.abs(v) >= 10 ? 0 : 2);
    $("vmin").textContent = scale.vmin.toFixed(digits(scale.vmin));
    $("vmax").textContent = scale.vmax.toFixed(digits(scale.vmax));
    $("unit").textContent = scale.unit;
  }

  // The map canvas: a background (prescription, path, field) drawn again only when the view, the run,
  // the layer choice or the size changes; per frame only the applied layer, the trail and the tractor.
  let background = null, backgroundKey = "";

  function drawMap() {
    const cv = $("map"), box = cv.getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    if (!grid) return;
    const wM = grid.cols * grid.cell_x_m, hM = grid.rows * grid.cell_y_m;
    const cssW = box.width, cssH = Math.min(cssW * hM / wM, window.innerHeight * 0.78);
    const scale = Math.min(cssW / wM, cssH / hM);
    if (cv.width !== Math.round(cssW * dpr) || cv.height !== Math.round(cssH * dpr)) {
      cv.width = Math.round(cssW * dpr);
      cv.height = Math.round(cssH * dpr);
      cv.style.height = `${cssH}px`;
    }
    const ox = (cssW - wM * scale) / 2, oy = (cssH - hM * scale) / 2;
    const X = (x) => ox + (x - grid.west_m) * scale, Y = (y) => oy + (grid.north_m - y) * scale;
    const which = document.querySelector("input[name=layer]:checked").value;
    const key = [cv.width, cv.height, S.mapVersion, mapImgVersion, S.runId, !!run.field, which].join();
    if (key !== backgroundKey) {
      backgroundKey = key;
      background = drawBackground(cv.width, cv.height, dpr, X, Y, ox, oy, wM * scale, hM * scale, which);
    }
    const c = cv.getContext("2d");
    c.setTransform(1, 0, 0, 1, 0, 0);
    c.clearRect(0, 0, cv.width, cv.height);
    c.drawImage(background, 0, 0);
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.imageSmoothingEnabled = false;
    if (layer && which !== "prescription") c.drawImage(layer, ox, oy, wM * scale, hM * scale);
    if (run.field) {
      c.lineWidth = 2;
      c.strokeStyle = "#222";
      for (const ring of run.field.boundary) polyline(c, ring, X, Y, true);
    }
    if (trail.length > 1) {
      c.lineWidth = 2;
      c.strokeStyle = "rgba(214,59,47,0.6)";
      polyline(c, trail, X, Y, false);
    }
    const p = S.pose;
    if (p && p.x_m !== null) {
      c.lineWidth = 2;
      c.strokeStyle = "#fff";
      c.beginPath();
      c.arc(X(p.measured_x_m), Y(p.measured_y_m), 6, 0, 2 * Math.PI);
      c.stroke();
      c.save();
      c.translate(X(p.x_m), Y(p.y_m));
      c.rotate(-p.heading_rad); // counter-clockwise from east; the canvas turns clockwise
      c.beginPath();
      c.moveTo(11, 0); c.lineTo(-7, 6); c.lineTo(-7, -6); c.closePath();
      c.fillStyle = "#d63b2f";
      c.fill();
      c.strokeStyle = "#fff";
      c.lineWidth = 1.5;
      c.stroke();
      c.restore();
    }
  }

  function drawBackground(width, height, dpr, X, Y, ox, oy, w, h, which) {
    const bg = document.createElement("canvas");
    bg.width = width;
    bg.height = height;
    const c = bg.getContext("2d");
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.imageSmoothingEnabled = false;
    S.mapShown = mapImg ? mapImgVersion : null;
    if (mapImg && which !== "applied") {
      c.globalAlpha = which === "both" ? 0.35 : 1;
      c.drawImage(mapImg, ox, oy, w, h);
      c.globalAlpha = 1;
    }
    if (run.field) {
      c.lineWidth = 1;
      c.setLineDash([4, 3]);
      c.strokeStyle = "rgba(255,255,255,0.8)";
      polyline(c, run.field.path, X, Y, false);
    }
    return bg;
  }

  function polyline(c, pts, X, Y, close) {
    if (!pts || pts.length < 2) return;
    c.beginPath();
    c.moveTo(X(pts[0][0]), Y(pts[0][1]));
    for (let k = 1; k < pts.length; k++) c.lineTo(X(pts[k][0]), Y(pts[k][1]));
    if (close) c.closePath();
    c.stroke();
  }

  // ------------------------------------------------------------------ charts
  // The run's rates arrive in kg/ha; shown in the map's own unit (the run's rate_unit, per_kg_ha).
  function rateUnit() {
    const f = run.per_kg_ha;
    return typeof run.rate_unit === "string" && typeof f === "number" && f > 0 ? [run.rate_unit, f] : ["kg/ha", 1];
  }

  function drawChart(id, a, b, colours, factor = 1) {
    const cv = $(id), dpr = window.devicePixelRatio || 1, w = cv.clientWidth, h = 170;
    if (cv.width !== Math.round(w * dpr)) { cv.width = Math.round(w * dpr); cv.height = Math.round(h * dpr); }
    const c = cv.getContext("2d");
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.clearRect(0, 0, w, h);
    const pts = points.filter((p) => p[a] !== null || p[b] !== null)
      .map((p) => (factor === 1 ? p : p.map((v, k) => ((k === a || k === b) && v !== null ? v * factor : v))));
    const L = 44, R = 6, T = 6, B = 20;
    c.strokeStyle = "#ccc";
    c.strokeRect(L, T, w - L - R, h - T - B);
    if (pts.length < 1) return;
    let lo = Infinity, hi = -Infinity;
    for (const p of pts) for (const k of [a, b]) if (p[k] !== null) { lo = Math.min(lo, p[k]); hi = Math.max(hi, p[k]); }
    if (!(hi > lo)) { hi = lo + 1; lo -= 1; }
    const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
    const t0 = pts[0][0], t1 = Math.max(pts[pts.length - 1][0], t0 + 1e-9);
    const X = (t) => L + (t - t0) / (t1 - t0) * (w - L - R), Y = (v) => T + (hi - v) / (hi - lo) * (h - T - B);
    c.fillStyle = "#666";
    c.font = "11px system-ui";
    for (const v of [lo + pad, (lo + hi) / 2, hi - pad]) c.fillText(v.toFixed(v < 10 ? 1 : 0), 2, Y(v) + 4);
    c.fillText(`${t0.toFixed(1)} s`, L, h - 5);
    const end = `${t1.toFixed(1)} s (sim time)`;
    c.fillText(end, w - R - c.measureText(end).width, h - 5);
    [[a, colours[0]], [b, colours[1]]].forEach(([k, colour]) => {
      c.strokeStyle = colour;
      c.lineWidth = 1.5;
      c.beginPath();
      let open = false;
      for (const p of pts) {
        if (p[k] === null) { open = false; continue; }
        if (open) c.lineTo(X(p[0]), Y(p[k])); else c.moveTo(X(p[0]), Y(p[k]));
        open = true;
      }
      c.stroke();
    });
  }

  // ------------------------------------------------------------------ tables
  const STATUS_ROWS = [
    ["state", "state"], ["scenario", "scenario"], ["clock", "clock"], ["ticks", "ticks", 0],
    ["sim time, s", "sim_time_s", 1], ["wall time, s", "wall_s", 1],
    ["real time ×, asked / kept", "realtime"], ["monitor ticks", "monitor_ticks", 0],
    ["per-tick MAE (live), kg/ha", "live_mae_kg_ha", 2], ["services missing", "missing"], ["error", "error"],
  ];
  // What each MAE is (the two differ by definition: docs/api.md, "The web page").
  const TITLES = {
    live_mae_kg_ha: "mean |applied − prescribed| over the rate samples with the implement on, each tick alike, " +
      "the prescription taken at the landing point the controller predicted (the monitor's live figure)",
    mae_kg_ha: "mean |applied − prescribed| over the covered cells of the as-applied map, product put where it " +
      "landed on the true path (the report's figure, as vrsim run reports it; docs/metrics.md)",
    realtime: "simulated seconds per wall second since the first tick: asked (realtime clock) and kept",
  };
  const REPORT_ROWS = [
    ["applied, kg", "applied_kg", 1], ["prescribed, kg", "prescribed_kg", 1],
    ["mass balance, %", "mass_balance_pct", 2], ["MAE over covered cells, kg/ha", "mae_kg_ha", 2],
    ["RMSE, kg/ha", "rmse_kg_ha", 2],
    ["bias, kg/ha", "bias_kg_ha", 2], ["within ±5 %, % area", "within_5pct_area_pct", 1],
    ["within ±10 %, % area", "within_10pct_area_pct", 1], ["coverage, %", "coverage_pct", 1],
    ["transitions", "transitions", 0], ["transition time, s", "transition_time_s_mean", 2],
    ["off target, kg", "off_target_kg", 2], ["ticks", "ticks", 0],
  ];

  function fill(id, rows, doc) {
    const body = $(id).tBodies[0];
    body.replaceChildren(...rows.map(([label, key, digits]) => {
      const tr = document.createElement("tr");
      let v = doc[key];
      if (Array.isArray(v)) v = v.join(", ") || "none";
      else if (typeof v === "number") v = digits === undefined ? String(v) : fixed(v, digits);
      else if (v === null || v === undefined || v === "") v = "-";
      tr.innerHTML = "<td></td><td></td>";
      tr.cells[0].textContent = label;
      tr.cells[1].textContent = v;
      if (TITLES[key]) tr.title = TITLES[key];
      return tr;
    }));
  }

  function fixed(v, digits) {
    return v.toFixed(digits).replace(/^-(0\.?0*)$/, "$1"); // no "-0.00"
  }

  // "×40 / ×13.5" (realtime), "as fast as it goes / ×310" (lockstep); S.realtime for scripts and tests.
  function realtimeText(st) {
    const asked = st.realtime_factor_asked, kept = st.realtime_factor;
    const x = (v) => `×${v >= 100 ? v.toFixed(0) : v >= 10 ? v.toFixed(1) : v.toFixed(2)}`;
    S.realtime = { asked: typeof asked === "number" ? asked : null, kept: typeof kept === "number" ? kept : null };
    const a = typeof asked === "number" ? x(asked) : st.clock === "lockstep" ? "as fast as it goes" : "-";
    const k = typeof kept === "number" ? x(kept) : "-";
    const short = typeof asked === "number" && typeof kept === "number" && kept < 0.9 * asked &&
      st.state === "running" ? " (behind)" : "";
    return `${a} / ${k}${short}`;
  }

  function showStatus(st) {
    const [unit, factor] = rateUnit(), doc = { ...st, realtime: realtimeText(st) };
    if (typeof st.live_mae_kg_ha === "number") doc.live_mae_kg_ha = st.live_mae_kg_ha * factor;
    fill("statusTable", STATUS_ROWS.map(([l, k, d]) => [l.replace("kg/ha", unit), k, d]), doc);
    $("state").textContent = st.state;
    $("state").className = `badge ${st.state}`;
  }

  // The report's rate figures in the map's own unit (rate_unit, in_rate_unit), as `vrsim run` prints them.
  function showReport(rep) {
    const unit = typeof rep.rate_unit === "string" ? rep.rate_unit : null, own = rep.in_rate_unit || {};
    const doc = { ...rep };
    showPartial(rep);
    const rows = REPORT_ROWS.map(([label, key, digits]) => {
      const v = own[key.replace(/_kg_ha$/, "")];
      if (!unit || !key.endsWith("_kg_ha") || typeof v !== "number") return [label, key, digits];
      doc[key] = v;
      return [label.replace("kg/ha", unit), key, digits];
    });
    fill("reportTable", rows, doc);
  }

  // A report that is not of a whole finished run says so: its coverage and mass balance are of the
  // ticks so far (the monitor's `complete`, `end_reason`, `missing_ticks`).
  function showPartial(rep) {
    const partial = rep.complete !== true, ticks = typeof rep.ticks === "number" ? rep.ticks : "?";
    const why = {
      unknown: `the run so far, ${ticks} ticks: not final`,
      stopped: `the run was stopped after ${ticks} ticks`,
      failed: `the run failed after ${ticks} ticks`,
      interrupted: `the run was interrupted after ${ticks} ticks`,
      finished: "ticks missing from the monitor's records",
    }[rep.end_reason] || `${ticks} ticks: not final`;
    S.reportPartial = partial;
    $("reportTable").classList.toggle("partial", partial);
    $("reportState").textContent = partial ? `partial: ${why}` : "final: the whole run";
  }

  function showCatchup() {
    const c = S.catchup;
    $("catchup").textContent = c && c.state !== "none"
      ? `${c.ticks} ticks of this run from the monitor's records, from before this view saw it live ` +
        `(${c.state}${c.note ? ": " + c.note : ""})`
      : "";
  }

  // ------------------------------------------------------------------ operator
  async function operate(verb) {
    $("opmsg").textContent = "";
    let url = `/api/${verb}`, body = null;
    const headers = { "Content-Type": "text/plain", "X-CSRF-Token": csrf };
    if (verb === "start") {
      url += `?clock=${encodeURIComponent($("clock").value)}&speed=${encodeURIComponent($("speed").value)}`;
      // The scenario with the files it names (or a .zip of them): uploaded, kept by the service under its
      // data root and started from there. None: the built-in default.
      const chosen = [...$("scenario").files];
      body = "";
      if (chosen.length) {
        body = new FormData();
        for (const f of chosen) body.append("files", f, f.name);
        delete headers["Content-Type"]; // the browser sets multipart/form-data with its boundary
      }
    }
    const r = await fetch(url, { method: "POST", body, headers: withKey(headers) });
    const doc = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
    if (!r.ok) $("opmsg").textContent = doc.error || `HTTP ${r.status}`;
  }
  $("start").onclick = () => operate("start");
  $("stop").onclick = () => operate("stop");
  document.querySelectorAll("input[name=layer]").forEach((el) => { el.onchange = () => { dirty = true; }; });
  window.addEventListener("resize", () => { dirty = true; });

  // ------------------------------------------------------------------ drawing, at most once a display frame
  function draw() {
    if (dirty) {
      dirty = false;
      drawMap();
      drawChart("shaftChart", 1, 2, ["#e07b00", "#1f5fbf"]);
      drawChart("rateChart", 3, 4, ["#555", "#1d8a4a"], rateUnit()[1]);
      S.draws++;
    }
    requestAnimationFrame(draw);
  }
  function start() {
    pickKey().then((ok) => { if (ok) { stream(); loadView(null); } }, () => setTimeout(start, 1000));
  }
  start();
  requestAnimationFrame(draw);
})();
