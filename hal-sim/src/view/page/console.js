// The bench console's page: the live stream of `fpc-sim view` over its WebSocket, drawn
// with uPlot; the controls sent back as JSON (hal-sim/src/view/protocol.rs). Units as the
// project's plots: time s, position mm, force N, pressure kPa, angle °.
"use strict";

const WINDOW_S = 4;      // the scrolling window of the live plots, s
const SPAN_S = 3;        // the position span is measured over this much of the window, s
const DRAW_EVERY_MS = 50;
const RATE_WINDOW_S = 2; // the frame rate shown is counted over this long, s
const LOG_LINES = 200;
const C = { black: "#000000", orange: "#E69F00", sky: "#56B4E9", green: "#009E73",
            blue: "#0072B2", vermillion: "#D55E00", purple: "#CC79A7" };

const $ = (id) => document.getElementById(id);
const COLUMNS = ["t", "x", "x_ref", "f_master", "f_slave", "p_a", "p_b", "theta"];
const buf = { start: 0 };
COLUMNS.forEach((c) => (buf[c] = []));

let ws = null;
let dirty = false;
let lastDraw = 0;
let lagBase = null;         // the least (page time − board time) seen, s
const rateSamples = [];     // [page time s, frames received]
let lost = 0;

function chart(el, series, extra) {
  const opts = Object.assign({
    width: Math.max(300, el.parentElement.clientWidth - 10),
    height: 170,
    legend: { live: false },
    cursor: { show: false },
    scales: { x: { time: false } },
    series: [{ label: "t, s" }].concat(series),
    axes: [{ label: "t, s", size: 34 }, { size: 60, space: 20 }],
  }, extra || {});
  return new uPlot(opts, [[]].concat(series.map(() => [])), el);
}

const line = (label, stroke, dash) => ({ label, stroke, width: 1.5, dash, spanGaps: false, points: { show: false } });
const dots = (label, stroke) => ({ label, stroke, fill: stroke, paths: () => null, points: { show: true, size: 2, stroke, fill: stroke } });

const plots = {
  position: chart($("p-position"), [line("x (master encoder)", C.blue), line("reference", C.black, [6, 4])]),
  force: chart($("p-force"), [line("master", C.vermillion), line("slave", C.sky, [6, 4])]),
  pressure: chart($("p-pressure"), [line("chamber A", C.blue), line("chamber B", C.orange, [6, 4])]),
  angle: chart($("p-angle"), [dots("θ", C.purple)], { scales: { x: { time: false }, y: { range: [0, 360] } } }),
};
let scopePlot = null;

function log(text, level) {
  const li = document.createElement("li");
  li.textContent = text;
  li.className = level || "info";
  const ol = $("log");
  ol.appendChild(li);
  while (ol.children.length > LOG_LINES) ol.removeChild(ol.firstChild);
  ol.scrollTop = ol.scrollHeight;
}

function send(control) {
  if (ws && ws.readyState === WebSocket.OPEN) {
    ws.send(JSON.stringify(control));
  } else {
    log("not sent: the console is not connected", "refused");
  }
}

function onFrames(b) {
  const n = b.t.length;
  for (let i = 0; i < n; i++) {
    buf.t.push(b.t[i]);
    buf.x.push(b.x[i]);
    buf.x_ref.push(b.x_ref.length === n ? b.x_ref[i] : null);
    buf.f_master.push(b.f_master[i]);
    buf.f_slave.push(b.f_slave[i]);
    buf.p_a.push(b.p_a[i]);
    buf.p_b.push(b.p_b[i]);
    buf.theta.push(b.theta[i]);
  }
  const now = performance.now() / 1000;
  if (n > 0) {
    const tLast = b.t[n - 1];
    while (buf.start < buf.t.length && buf.t[buf.start] < tLast - WINDOW_S) buf.start++;
    if (buf.start > 100000) {
      COLUMNS.forEach((c) => (buf[c] = buf[c].slice(buf.start)));
      buf.start = 0;
    }
    const behind = now - tLast;
    lagBase = lagBase === null ? behind : Math.min(lagBase, behind);
    $("lag").textContent = ((behind - lagBase) * 1000).toFixed(0) + " ms";
    dirty = true;
  }
  rateSamples.push([now, b.frames]);
  while (rateSamples.length > 2 && now - rateSamples[1][0] >= RATE_WINDOW_S) rateSamples.shift();
  const [t0, f0] = rateSamples[0];
  if (now - t0 >= 0.5 * RATE_WINDOW_S) $("rate-shown").textContent = ((b.frames - f0) / (now - t0)).toFixed(0) + " frames/s";
  const state = $("state");
  state.textContent = b.mode;
  state.className = b.mode;
  $("homed").textContent = b.homed ? "homed" : "not homed";
  $("ports").textContent = b.ports;
  $("frames").textContent = b.frames;
  $("gaps").textContent = b.gaps;
  $("dropped").textContent = b.dropped;
  $("rejected").textContent = b.rejected;
  const fault = $("fault");
  if (b.fault) {
    fault.textContent = "FAULT: " + b.fault + " — the machine is in its safe state; clear faults once the cause is gone";
    fault.hidden = false;
  } else if (b.absent && b.absent.length) {
    fault.textContent = "WAITING: " + b.absent.join(", ") + " absent since boot — nothing is driven until they appear";
    fault.hidden = false;
  } else {
    fault.hidden = true;
  }
  const conn = $("conn");
  if (b.silent_s > 1.0) {
    conn.textContent = "no telemetry for " + b.silent_s.toFixed(0) + " s: is the board streaming?";
    conn.hidden = false;
  } else if (b.behind_s > 0.2) {
    conn.textContent = "the simulation runs " + b.behind_s.toFixed(1) + " s behind real time";
    conn.hidden = false;
  } else if (ws && ws.readyState === WebSocket.OPEN) {
    conn.hidden = true;
  }
}

function draw(ts) {
  requestAnimationFrame(draw);
  if (!dirty || ts - lastDraw < DRAW_EVERY_MS) return;
  dirty = false;
  lastDraw = ts;
  const s = (c) => buf[c].slice(buf.start);
  const t = s("t");
  plots.position.setData([t, s("x"), s("x_ref")]);
  plots.force.setData([t, s("f_master"), s("f_slave")]);
  plots.pressure.setData([t, s("p_a"), s("p_b")]);
  plots.angle.setData([t, s("theta")]);
  // The position's span over the last SPAN_S seconds.
  const tLast = t.length ? t[t.length - 1] : 0;
  let lo = Infinity, hi = -Infinity;
  for (let i = t.length - 1; i >= 0 && t[i] >= tLast - SPAN_S; i--) {
    const x = buf.x[buf.start + i];
    if (x < lo) lo = x;
    if (x > hi) hi = x;
  }
  $("span").textContent = hi >= lo ? "(span " + (hi - lo).toFixed(1) + " mm over the last " + SPAN_S + " s)" : "";
}
requestAnimationFrame(draw);

function onScope(m) {
  $("scope").hidden = false;
  $("scope-title").textContent = "recording " + m.id + ", trigger " + m.trigger + " (t = 0), 20 kHz";
  const el = $("p-scope");
  const data = [m.t_ms, m.x, m.f_master, m.f_slave, m.p_a, m.p_b];
  if (!scopePlot) {
    scopePlot = new uPlot({
      width: Math.max(300, el.parentElement.clientWidth - 10),
      height: 220,
      legend: { live: false },
      cursor: { show: false },
      scales: { x: { time: false } },
      series: [{ label: "t, ms" },
               Object.assign(line("x, mm", C.blue), { scale: "mm" }),
               Object.assign(line("master, N", C.vermillion), { scale: "N" }),
               Object.assign(line("slave, N", C.sky, [6, 4]), { scale: "N" }),
               Object.assign(line("A, kPa", C.green), { scale: "kPa" }),
               Object.assign(line("B, kPa", C.orange, [6, 4]), { scale: "kPa" })],
      axes: [{ label: "t from the trigger, ms" }, { scale: "mm", label: "mm", size: 55 },
             { scale: "N", side: 1, label: "N", size: 60 }, { scale: "kPa", side: 1, label: "kPa", size: 60 }],
    }, data, el);
  } else {
    scopePlot.setData(data);
  }
}

function onMessage(ev) {
  const m = JSON.parse(ev.data);
  switch (m.type) {
    case "hello":
      $("source").textContent = m.source;
      $("version").textContent = "fpc-sim " + m.version;
      document.title = "fpc bench console — " + m.source;
      break;
    case "frames": onFrames(m); break;
    case "log":
      if (m.text.startsWith("this page fell behind")) {
        const k = parseInt(m.text.replace(/\D+/, ""), 10);
        if (k > 0) { lost += k; $("lost").textContent = lost + " batches"; }
      }
      log(m.text, m.level);
      break;
    case "scope": onScope(m); break;
    case "recording": {
      const b = $("record");
      b.classList.toggle("on", m.on);
      b.textContent = m.on ? "End recording" : "Record";
      $("recording").textContent = m.on ? "recording to " + m.dir : "";
      $("rec-state").textContent = m.on ? "● recording" : "";
      break;
    }
  }
}

function connect() {
  ws = new WebSocket("ws://" + location.host + "/ws");
  ws.onopen = () => { $("conn").hidden = true; };
  ws.onmessage = onMessage;
  ws.onclose = () => {
    const conn = $("conn");
    conn.textContent = "connection lost: fpc-sim view is not reachable (retrying every second)";
    conn.hidden = false;
    $("state").textContent = "unknown";
    $("state").className = "";
    setTimeout(connect, 1000);
  };
}

$("home").onclick = () => send({ cmd: "home" });
$("stop").onclick = () => send({ cmd: "stop" });
$("clear").onclick = () => send({ cmd: "clear_faults" });
$("start").onclick = () => {
  const speed = $("speed").value.trim();
  send({ cmd: "start", pressure_ratio: parseFloat($("pr").value),
         speed_mps: speed === "" ? null : parseFloat(speed), rotation: $("rotation").value });
};
$("calibrate").onclick = () => send({ cmd: "calibrate", routine: $("routine").value });
$("telemetry").onclick = () => send({ cmd: "telemetry", rate_hz: parseFloat($("rate").value), channels: $("channels").value });
$("arm").onclick = () => send({ cmd: "scope_arm", trigger: $("trigger").value, pre: parseInt($("pre").value, 10) || 0 });
$("fire").onclick = () => send({ cmd: "scope_fire" });
$("record").onclick = () => send({ cmd: "record", on: !$("record").classList.contains("on") });
window.addEventListener("resize", () => {
  for (const p of Object.values(plots)) p.setSize({ width: Math.max(300, p.root.parentElement.clientWidth - 10), height: 170 });
});
connect();
