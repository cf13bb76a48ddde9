// rtlift live view: batches from /ws (rtlift/app/view/server.py) into three uPlot charts.
"use strict";

const COLS = ["t", "meas", "est", "model", "innov", "band", "nis"];
const NIS_97_5 = 5.024;   // upper edge of the central 95 % interval of chi-square(1)
const buf = Object.fromEntries(COLS.map((k) => [k, []]));
let windowS = 30;
let paused = false;
let updates = 0;
let finished = false;
let syncing = false;
const charts = [];

function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }

function setState(text, kind) {
  const el = document.getElementById("state");
  el.textContent = text;
  el.dataset.state = kind;
}

function chart(el, title, series, extra) {
  const width = el.clientWidth || 900;
  const opts = Object.assign({
    title, width, height: 170,
    scales: { x: { time: false } },
    axes: [{ label: "t (s)" }, { space: 20, size: 60 }],
    cursor: { sync: { key: "rtlift" }, drag: { x: true, y: false } },
    series: [{ label: "t (s)" }].concat(series),
    hooks: {
      setSelect: [() => { pause(true); }],
      setScale: [(u, key) => {
        if (key !== "x" || syncing) return;
        syncing = true;
        for (const c of charts) if (c !== u) c.setScale("x", { min: u.scales.x.min, max: u.scales.x.max });
        syncing = false;
      }],
    },
  }, extra || {});
  const u = new uPlot(opts, series.map(() => []).concat([[]]), el);
  charts.push(u);
  return u;
}

const dclChart = chart(document.getElementById("plot-dcl"), "ΔCL", [
  { label: "measured", stroke: "#9aa", width: 1 },
  { label: "observer ΔĈL", stroke: "#c22", width: 2 },
  { label: "open-loop model", stroke: "#26c", width: 1, dash: [6, 4] },
]);
const innovChart = chart(document.getElementById("plot-innov"), "innovation ν with ±2σ", [
  { label: "ν", stroke: "#333", width: 1 },
  { label: "+2σ", stroke: "#e90", width: 1 },
  { label: "−2σ", stroke: "#e90", width: 1 },
], { bands: [{ series: [2, 3], fill: "rgba(238,153,0,0.15)" }] });
const nisChart = chart(document.getElementById("plot-nis"), "NIS ν²/S", [
  { label: "NIS", stroke: "#639", width: 1 },
  { label: "χ²₁ 97.5 %", stroke: "#aaa", width: 1, dash: [4, 4] },
], { scales: { x: { time: false }, y: { range: (u, min, max) => [0, Math.max(8, max || 0)] } } });

function render() {
  const t = buf.t.slice();
  const neg = buf.band.map((b) => (b === null ? null : -b));
  dclChart.setData([t, buf.meas.slice(), buf.est.slice(), buf.model.slice()]);
  innovChart.setData([t, buf.innov.slice(), buf.band.slice(), neg]);
  nisChart.setData([t, buf.nis.slice(), t.map(() => NIS_97_5)]);
}

function pause(on) {
  paused = on;
  document.getElementById("pause").textContent = on ? "Resume" : "Pause";
  if (!finished) setState(on ? "paused" : "running", on ? "paused" : "running");
  if (!on) render();
}
document.getElementById("pause").addEventListener("click", () => pause(!paused));

function showCounters(c) {
  for (const [k, v] of Object.entries(c || {})) {
    const el = document.getElementById("c-" + k);
    if (el) { el.textContent = String(v); el.dataset.value = String(v); }
  }
}

function append(msg) {
  if (!msg.t || msg.t.length === 0) return;
  if (buf.t.length && msg.t[0] <= buf.t[buf.t.length - 1]) for (const k of COLS) buf[k] = [];  // a new run
  for (const k of COLS) for (const x of msg[k]) buf[k].push(x);
  const tLast = buf.t[buf.t.length - 1];
  let drop = 0;
  while (drop < buf.t.length && buf.t[drop] < tLast - windowS) drop++;
  if (drop) for (const k of COLS) buf[k].splice(0, drop);
  const i = buf.t.length - 1;
  document.getElementById("v-t").textContent = fmt(buf.t[i], 2);
  document.getElementById("v-meas").textContent = fmt(buf.meas[i], 4);
  document.getElementById("v-est").textContent = fmt(buf.est[i], 4);
  document.getElementById("v-model").textContent = fmt(buf.model[i], 4);
  document.getElementById("v-nis").textContent = fmt(buf.nis[i], 2);
}

function onMessage(ev) {
  const msg = JSON.parse(ev.data);
  if (msg.kind === "hello") {
    document.getElementById("title").textContent = msg.title;
    document.title = msg.title + " — rtlift live view";
    windowS = msg.window_s;
    for (const k of COLS) buf[k] = [];
    finished = false;
    if (!paused) setState("running", "running");
  }
  if (msg.kind === "final") {
    finished = true;
    setState("ended: " + msg.end, "ended");
    document.getElementById("v-latency").textContent =
      msg.latency_p50_ms === null ? "–" : fmt(msg.latency_p50_ms, 3) + " / " + fmt(msg.latency_p99_ms, 3) + " ms";
  } else {
    append(msg);
  }
  showCounters(msg.counters);
  updates += 1;
  document.getElementById("v-updates").textContent = String(updates);
  if (!paused) render();
}

function connect() {
  const ws = new WebSocket("ws://" + location.host + "/ws");
  ws.onmessage = onMessage;
  ws.onclose = () => {
    if (finished) return;
    setState("disconnected", "disconnected");
    setTimeout(connect, 1000);
  };
}

window.addEventListener("resize", () => {
  for (const c of charts) c.setSize({ width: c.root.parentElement.clientWidth, height: 170 });
});
connect();
