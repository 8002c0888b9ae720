// The web console's page: operator once per browser, task picker, live endoscope view, keyboard / gamepad, session
// buttons. Everything it loads comes from the server it was served by; it sends JSON text only.
"use strict";

const token = new URLSearchParams(location.search).get("token") || "";
const $ = (id) => document.getElementById(id);
// The keys the server maps (both hands of the keyboard device's layouts) and the session keys.
const MOTION_KEYS = new Set("wsdaqezxcvtiklju om,nby".replace(" ", "").split(""));
const SESSION_KEYS = { r: "redo", f: "discard", enter: "save", escape: "end" };
// Gamepad (standard mapping) buttons that press session keys: X redo, Y discard, Back end, Start save.
const PAD_COMMANDS = { 2: "redo", 3: "discard", 8: "end", 9: "save" };
const LATENCY_BATCH_MS = 1000;

const state = {
  ws: null, seq: 0, held: new Set(), playing: false, task: null, tasks: [], pendingInputs: new Map(),
  latencyBatch: [], lastPad: "", padPressed: new Set(), connected: false,
};
// What the tests and the benchmark read: frames shown, their times, and the input-to-frame latencies measured.
window.consoleStats = { frames: 0, frameTimes: [], latencies: [], hud: null, status: [], lastAck: -1, sent: 0 };

// ------------------------------------------------------------------ the operator, once per browser
function operator() {
  return { id: localStorage.getItem("surrol.operator"), skill: localStorage.getItem("surrol.skill") };
}

function askOperator() {
  const who = operator();
  $("who-id").value = who.id || "";
  $("who-skill-select").value = who.skill || "novice";
  $("who").showModal();
}

$("who-form").addEventListener("submit", (event) => {
  const id = $("who-id").value.trim();
  if (!/^[A-Za-z0-9_.@+\-]{1,64}$/.test(id)) { event.preventDefault(); return; }
  const changed = operator().id && operator().id !== id;
  localStorage.setItem("surrol.operator", id);
  localStorage.setItem("surrol.skill", $("who-skill-select").value);
  showOperator();
  if (changed || state.connected) location.reload();   // a new operator starts a new session
  else connect();
});
$("who-change").addEventListener("click", askOperator);

function showOperator() {
  const who = operator();
  $("who-name").textContent = who.id || "?";
  $("who-skill").textContent = who.skill ? `(${who.skill})` : "";
}

// ------------------------------------------------------------------ tasks
async function loadTasks() {
  const reply = await fetch(`/api/tasks?token=${encodeURIComponent(token)}`);
  if (!reply.ok) { setStatus("this address needs the access token the server printed (…/?token=…)"); return false; }
  const data = await reply.json();
  state.tasks = data.tasks.map((t) => t.name);
  const list = $("tasks");
  for (const t of data.tasks) {
    const li = document.createElement("li");
    li.dataset.task = t.name;
    li.tabIndex = 0;
    const img = document.createElement("img");
    img.src = `/api/tasks/${encodeURIComponent(t.name)}.png`;
    img.alt = "";
    const name = document.createElement("b");
    name.textContent = t.name;
    const text = document.createElement("span");
    text.textContent = t.description;
    li.append(img, name, text);
    li.addEventListener("click", () => chooseTask(t.name));
    li.addEventListener("keydown", (e) => { if (e.key === "Enter") chooseTask(t.name); });
    list.append(li);
  }
  const last = localStorage.getItem("surrol.task");
  state.task = state.tasks.includes(last) ? last : state.tasks[0];
  markTask(state.task);
  return true;
}

function markTask(task) {
  for (const li of $("tasks").children) li.classList.toggle("chosen", li.dataset.task === task);
}

function chooseTask(task) {
  if (state.playing) { setStatus("end the session first (Esc) to change the task"); return; }
  state.task = task;
  localStorage.setItem("surrol.task", task);
  markTask(task);
  send({ type: "task", name: task });
}

// ------------------------------------------------------------------ the connection
function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${proto}://${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = "arraybuffer";
  state.ws = ws;
  let header = null;
  ws.onopen = () => {
    state.connected = true;
    const who = operator();
    send({ type: "hello", operator: who.id, skill: who.skill, task: state.task });
    setPlaying(false);
    overlay("starting your simulator…");
  };
  ws.onmessage = (event) => {
    if (typeof event.data !== "string") { if (header) showFrame(header, event.data); header = null; return; }
    const message = JSON.parse(event.data);
    if (message.type === "frame") header = message;
    else onControl(message);
  };
  ws.onclose = () => {
    state.connected = false;
    setPlaying(false);
    overlay("disconnected: reload the page to start again");
  };
}

function send(message) {
  if (state.ws && state.ws.readyState === WebSocket.OPEN) state.ws.send(JSON.stringify(message));
}

function onControl(message) {
  if (message.type === "status") setStatus(message.data);
  else if (message.type === "error") setStatus(`refused: ${message.text}`);
  else if (message.type === "task") {
    state.task = message.data.task;
    markTask(state.task);
    state.keyboardKeys = message.data.keys;
    showKeys();
    overlay("");
    setStatus(`${state.task}: press Play`);
  } else if (message.type === "session_ended") {
    const s = message.data;
    setPlaying(false);
    setStatus(`session ended: ${s.kept} saved, ${s.discarded} discarded, ${s.redone} redone`);
  }
}

function showKeys() {
  $("keys").textContent = "";
  for (const line of keyLines(state.keyboardKeys || [])) {
    const div = document.createElement("div");
    div.textContent = line;
    $("keys").append(div);
  }
}

function keyLines(keyboard) {
  if ($("device").value === "gamepad") {
    return ["left stick: left/right and toward/away   right stick: up/down   LB/RB roll   A jaw   B clutch",
            "Start save   X redo   Y discard   Back end the session"];
  }
  return [...keyboard, "Enter save   r redo   f discard   Esc end the session"];
}

// ------------------------------------------------------------------ frames
async function showFrame(header, jpeg) {
  const bitmap = await createImageBitmap(new Blob([jpeg], { type: "image/jpeg" }));
  const canvas = $("frame");
  if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) {
    canvas.width = bitmap.width; canvas.height = bitmap.height;
  }
  canvas.getContext("2d").drawImage(bitmap, 0, 0);
  bitmap.close();
  const now = performance.now();
  const stats = window.consoleStats;
  stats.frames += 1;
  stats.frameTimes.push(now);
  if (stats.frameTimes.length > 2000) stats.frameTimes.shift();
  stats.hud = header.hud;
  stats.lastAck = header.ack;
  for (const [seq, sent] of state.pendingInputs) {
    if (seq > header.ack) continue;
    state.pendingInputs.delete(seq);
    if (!header.hud.playing) continue;
    const ms = now - sent;
    stats.latencies.push(ms);
    state.latencyBatch.push(Math.round(ms * 10) / 10);
  }
  if (header.hud.playing !== state.playing) setPlaying(header.hud.playing);
  showHud(header.hud);
}

function showHud(h) {
  if (!h.playing && h.attempt === 0) { $("hud").textContent = `${state.task}\npress Play to start`; return; }
  const limit = h.limit_s == null ? "" : ` / ${h.limit_s.toFixed(0)}`;
  const arms = h.jaw_closed.length === 2 ? ["PSM1", "PSM2"] : [""];
  const lines = [
    `${state.task}   attempt ${h.attempt}   browser ${$("device").value}`,
    `time ${h.time_s.toFixed(1)}${limit} s   path ${h.path_cm.toFixed(1)} cm   success ${h.success ? "YES" : "no"}`,
    arms.map((a, i) => `${a} jaw ${h.jaw_closed[i] ? "closed" : "open"}  clutch ${h.clutch[i] ? "ON" : "off"}`.trim())
      .join("   "),
  ];
  if (h.timed_out) lines.push("TIME UP: Enter keeps this attempt, f drops it, r redoes it");
  $("hud").textContent = lines.join("\n");
  $("hud").classList.toggle("success", h.success);
}

setInterval(() => {
  if (state.latencyBatch.length) send({ type: "latency", ms: state.latencyBatch.splice(0, 100) });
}, LATENCY_BATCH_MS);

// ------------------------------------------------------------------ input
function sendInput(fields) {
  state.seq += 1;
  window.consoleStats.sent = state.seq;
  if (state.playing) state.pendingInputs.set(state.seq, performance.now());
  send({ type: "input", seq: state.seq, ...fields });
}

function command(name) {
  if (name === "play") {
    send({ type: "command", name: "play", device: $("device").value });
    return;
  }
  send({ type: "command", name });
}

function keyName(event) { return event.key.length === 1 ? event.key.toLowerCase() : event.key.toLowerCase(); }

window.addEventListener("keydown", (event) => {
  if ($("who").open || event.target.tagName === "INPUT" || event.target.tagName === "SELECT") return;
  const key = keyName(event);
  if (SESSION_KEYS[key]) {
    event.preventDefault();
    if (!event.repeat && state.playing) command(SESSION_KEYS[key]);
    return;
  }
  if (!MOTION_KEYS.has(key) || $("device").value !== "keyboard") return;
  event.preventDefault();
  if (state.held.has(key)) return;   // auto-repeat: still held
  state.held.add(key);
  sendInput({ keys: [...state.held] });
});
window.addEventListener("keyup", (event) => {
  const key = keyName(event);
  if (!state.held.delete(key)) return;
  sendInput({ keys: [...state.held] });
});
window.addEventListener("blur", () => {   // keys released while the page had no focus never send a keyup
  if (state.held.size) { state.held.clear(); sendInput({ keys: [] }); }
});

function pollPad() {
  requestAnimationFrame(pollPad);
  if ($("device").value !== "gamepad") return;
  const pad = [...(navigator.getGamepads ? navigator.getGamepads() : [])].find((p) => p);
  if (!pad) return;
  const axes = pad.axes.slice(0, 4).map((v) => Math.round(v * 100) / 100);
  const buttons = pad.buttons.slice(0, 17).map((b) => Math.round(b.value * 100) / 100);
  const snapshot = JSON.stringify([axes, buttons]);
  if (snapshot !== state.lastPad) {
    state.lastPad = snapshot;
    sendInput({ axes, buttons, pad: pad.id.slice(0, 80) });
  }
  for (const [index, name] of Object.entries(PAD_COMMANDS)) {
    const down = pad.buttons[index] && pad.buttons[index].pressed;
    if (down && !state.padPressed.has(index) && state.playing) command(name);
    if (down) state.padPressed.add(index); else state.padPressed.delete(index);
  }
}
window.addEventListener("gamepadconnected", (e) => setStatus(`gamepad connected: ${e.gamepad.id}`));
requestAnimationFrame(pollPad);

// ------------------------------------------------------------------ buttons and status
for (const name of ["play", "save", "redo", "discard", "end"]) {
  $(name).addEventListener("click", () => { command(name); $(name).blur(); });
}
$("device").addEventListener("change", () => { $("device").blur(); showKeys(); });

function setPlaying(playing) {
  state.playing = playing;
  $("play").disabled = playing || !state.connected;
  for (const name of ["save", "redo", "discard", "end"]) $(name).disabled = !playing;
  $("device").disabled = playing;
  document.body.classList.toggle("playing", playing);
  if (!playing) state.pendingInputs.clear();
}

function setStatus(text) {
  $("status").textContent = text;
  window.consoleStats.status.push(text);
}

function overlay(text) {
  $("overlay").textContent = text;
  $("overlay").hidden = !text;
}

// ------------------------------------------------------------------ start
(async () => {
  setPlaying(false);
  showOperator();
  if (!(await loadTasks())) { overlay("no access token"); return; }
  if (!operator().id) askOperator(); else connect();
})();
