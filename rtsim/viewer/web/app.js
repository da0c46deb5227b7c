// rtsim view: the page. A source of samples feeds the scene, the plots and the panel: the live service
// through the server's WebSocket (each drawn frame pulls what is new: the page sets its own rate, nothing
// queues for a slow page; the user's inputs go back as the service's `drive` commands), or one or two
// recordings the server sends whole, played here with a timeline (play, pause, scrub, speed); a second
// recording's car is drawn beside the first and its channels plotted dashed.
//
// Measured and shown:
// - frame rate: frames drawn over the last second;
// - key -> model input: the round trip of a drive command, from the input's time stamp on the page to the
//   service's reply, which it sends once the loop has put the command into the model's input arrays
//   (p50 and max over the last 50);
// - model -> screen: from the wall time the model produced a state sample (its simulation time mapped to
//   the service's clock with the status' wall_time; realtime mode) to the frame that draws it, on the
//   page's clock corrected by the offset to the server's clock (ping/pong); and server -> screen, from
//   the sample's arrival at the server to that frame (any mode).
import { Scene3D } from './scene.js';
import { Plots, tickLabels } from './plots.js';
import { Input } from './input.js';

const $ = (id) => document.getElementById(id);
const wall = () => (performance.timeOrigin + performance.now()) / 1000;     // s, the page's wall clock
const view = window.rtsimView = { ready: false, frames: 0, fps: 0, errors: [], latency: {}, drive: {}, pose: null };
window.addEventListener('error', (e) => view.errors.push(String(e.message)));
view.setVehicleVisible = (on) => { if (scene.vehicle) scene.vehicle.group.visible = on; };   // (tests: an empty scene)
view.marksDrawn = () => (scene.marks ? scene.marks.geometry.attributes.position.count / 3 : 0);   // road-mark triangles
view.setMarksVisible = (on) => { if (scene.marks) scene.marks.visible = on; };          // (tests)

const scene = new Scene3D($('view'));
const plots = new Plots($('plot-channels'), $('plot-health'), $('pick'));
const input = new Input();
view.input = input;          // (tests: the keys' ramped inputs, as the page drives with them)
view.plots = plots;
view.tickLabels = tickLabels;   // (tests: the axes' tick labels)
let info = null, state = null, sensors = null, status = null, commands = null;
let pulling = false, clockOffset = 0, bestPing = Infinity, simWall = null;
const simWallSamples = [];
let replay = null;          // a replay: {recs: [{state, sensors, status, times}], t, t0, t1, playing}
let driveSeq = 0, lastSent = null, lastSentAt = 0, newState = false, stateRx = 0;
const rtts = [], queries = [], screen = [], modelScreen = [];

function median(a) { if (!a.length) return null; const s = [...a].sort((x, y) => x - y); return s[s.length >> 1]; }
function keep(a, x, n = 50) { a.push(x); if (a.length > n) a.shift(); }
function fmt(x, d = 1) { return x == null || !Number.isFinite(x) ? '–' : x.toFixed(d); }

// ---- the source ---------------------------------------------------------------------------------------
const ws = new WebSocket(`ws://${location.host}/ws${location.search}`);   // ?token=…: the session's, when the server asks for one
ws.onmessage = (ev) => {
  const m = JSON.parse(ev.data);
  if (m.type === 'hello') {
    start(m.info, m.source);
    faultPanel(m.faults || [], m.may_drive !== false && m.source !== 'replay');
    if (m.may_drive === false) {        // served off loopback and this page's URL lacks the session token: watch only
      for (const id of ['drive', 'takeover', 'release', 'reset']) $(id).disabled = true;
      view.driveDeclined = true;
      view.drive.error = 'watching only: driving needs the URL with the session token that rtsim view printed';
    }
  }
  else if (m.type === 'recording') loaded(m);
  else if (m.type === 'data') take(m);
  else if (m.type === 'drive_ack') ack(m);
  else if (m.type === 'pong') {
    const now = wall(), rtt = now - m.client_time;
    if (rtt < bestPing) { bestPing = rtt; clockOffset = m.server_time - (m.client_time + now) / 2; }
  } else if (m.type === 'reset_ack') { if (!m.reply.ok) view.drive.error = m.reply.error; }
  else if (m.type === 'fault_ack') faultAck(m.reply);
  else if (m.type === 'error') view.errors.push('server: ' + m.error);
};
ws.onclose = () => { $('run').textContent = 'disconnected from the rtsim view server'; };
function ping() { if (ws.readyState === 1) ws.send(JSON.stringify({ type: 'ping', client_time: wall() })); }

function start(i, source) {
  info = view.info = i;
  $('vehicle').textContent = `${i.vehicle_id} · ${i.name}`;
  scene.build(i);
  if (source === 'replay') {
    replay = view.replay = { recs: [], t: 0, t0: 0, t1: 0, playing: false, speed: 1 };
    for (const r of i.replays.slice(1)) scene.addVehicle(r, '#1f5fbf');
    plots.suffixes = i.replays.length > 1 ? ['', ' (B)'] : [''];
    plots.cap = 1e7;
    plots.until = 0;
    plots.refill = refill;
    $('timeline').hidden = false;
    $('files').textContent = i.replays.map((r, k) => `${k ? 'B (blue)' : 'A (red)'}: ${r.file}`).join(' · ');
    for (const id of ['drive', 'takeover', 'release', 'settings-btn', 'reset']) $(id).disabled = true;
  }
  plots.init(i, i.plots);           // the vehicle's default channels
  if (source !== 'replay' && !i.controls.length) {
    $('drive').disabled = true;
    view.drive.error = 'this service does not describe its controls: driving is off (a newer rtsim serve does)';
  }
  if (i.road.note) $('run').textContent = i.road.note;
  for (let k = 0; k < 5; k++) setTimeout(ping, 200 * k);
  setInterval(() => { bestPing *= 1.02; ping(); }, 2000);     // (let the best sample age: clocks drift)
  requestAnimationFrame(frame);
}

// ---- a replay ----------------------------------------------------------------------------------------
function loaded(m) {
  const times = Float64Array.from(m.state, (s) => s.time);
  replay.recs[m.index] = { state: m.state, sensors: m.sensors, status: m.status, times, file: m.file,
    damage: m.damage, faults: m.faults || [] };
  if (m.damage && m.damage.damaged) {        // what the file lost and how its session ended, in view
    $('files').textContent += ` · ${m.index ? 'B' : 'A'}: ${m.health}`;
    $('files').style.color = '#b00020';
  }
  const all = replay.recs.filter(Boolean);
  replay.t0 = Math.min(...all.map((r) => r.times[0]));
  replay.t1 = Math.max(...all.map((r) => r.times[r.times.length - 1]));
  if (m.index === 0) replay.t = replay.t0;
  faultMarks();
  refill();
  view.replayLoaded = all.length;
}

function refill() {
  if (!replay) return;
  for (const s of plots.series.values()) { s.t.length = 0; s.v.length = 0; }
  for (const k in plots.health) plots.health[k].length = 0;
  replay.recs.forEach((r, k) => {
    if (!r) return;
    plots.push(r.state, k, 'state'); plots.push(r.sensors, k, 'sensors');
    if (k === 0) for (const st of r.status) plots.pushStatus(st);
  });
}

function atOrBefore(times, t) {                 // index of the last sample at or before t (the first if none)
  let lo = 0, hi = times.length;
  while (lo < hi) { const m = (lo + hi) >> 1; if (times[m] <= t + 1e-9) lo = m + 1; else hi = m; }
  return Math.max(0, lo - 1);
}

function showReplay(dt) {
  const R = replay;
  if (R.playing) {
    R.t += dt * R.speed;
    if (R.t >= R.t1) { R.t = R.t1; R.playing = false; $('play').textContent = 'play'; }
  }
  R.recs.forEach((r, k) => {
    if (!r) return;
    const i = atOrBefore(r.times, R.t);
    scene.update(r.state[i], r.sensors[i], dt, k);
    if (k === 0) {
      state = r.state[i];
      const j = r.status.length ? atOrBefore(Float64Array.from(r.status, (s) => s.time), R.t) : -1;
      status = j >= 0 ? r.status[j] : null;
    }
  });
  plots.until = R.t;
  plots.dirty = true;
  if (!view.scrubbing) $('scrub').value = String(Math.round(1000 * (R.t - R.t0) / Math.max(1e-9, R.t1 - R.t0)));
  $('ttext').textContent = `${R.t.toFixed(2)} / ${R.t1.toFixed(2)} s`;
  const on = activeFaults(R.t);
  $('tfaults').textContent = on.length ? `faults: ${on.join(', ')}` : '';
  view.activeFaults = on;
}

// the first recording's injected faults: a mark per onset (red) and end (grey) on the time bar, and the
// faults active at the time shown
function faultMarks() {
  const r = replay.recs[0], box = $('fault-marks');
  box.innerHTML = '';
  if (!r) return;
  const span = Math.max(1e-9, replay.t1 - replay.t0);
  for (const e of r.faults) {
    const el = document.createElement('span');
    el.className = e.event === 'end' ? 'end' : 'onset';
    el.style.left = `${(100 * Math.min(1, Math.max(0, (e.time - replay.t0) / span))).toFixed(2)}%`;
    el.title = `${e.id} (${e.kind} on ${e.target}) ${e.event} at ${e.time.toFixed(3)} s`;
    box.appendChild(el);
  }
}
function activeFaults(t) {
  const r = replay.recs[0], on = new Set();
  if (!r) return [];
  for (const e of r.faults) {                   // in recorded order: onsets and ends up to t
    if (e.time > t + 1e-9) break;
    if (e.event === 'onset') on.add(e.id); else on.delete(e.id);
  }
  return [...on];
}

// tests and scripts: show time t (s) of the recording(s), paused
view.seek = (t) => { if (replay) { replay.t = Math.min(replay.t1, Math.max(replay.t0, t)); replay.playing = false; } };
$('play').onclick = () => {
  if (!replay) return;
  if (replay.t >= replay.t1) replay.t = replay.t0;
  replay.playing = !replay.playing;
  $('play').textContent = replay.playing ? 'pause' : 'play';
};
$('scrub').oninput = () => { view.scrubbing = true; view.seek(replay.t0 + (replay.t1 - replay.t0) * Number($('scrub').value) / 1000); };
$('scrub').onchange = () => { view.scrubbing = false; };
$('speed').onchange = () => { if (replay) replay.speed = Number($('speed').value); };

function take(m) {
  pulling = false;
  if (m.state && m.state.length) {
    state = m.state[m.state.length - 1]; newState = true; stateRx = m.state_rx;
    plots.push(m.state, 0, 'state');
  }
  if (m.sensors && m.sensors.length) { sensors = m.sensors[m.sensors.length - 1]; plots.push(m.sensors, 0, 'sensors'); }
  if (m.commands && m.commands.length) commands = m.commands[m.commands.length - 1];
  if (m.status && m.status.length) {
    status = m.status[m.status.length - 1];
    plots.pushStatus(status);
    if (status.wall_time != null && status.mode === 'realtime') {
      keep(simWallSamples, status.wall_time - status.sim_time, 10);
      simWall = Math.min(...simWallSamples);     // the status is made after its step: the least offset is the best
    }
  }
}

// ---- driving ------------------------------------------------------------------------------------------
// The vehicle's control groups (info.controls, rtsim.vehicle.kit.user_inputs): touching a control takes
// over its group's channels only (the rest stay with the rider, the scenario's driver or the bus ECU); each
// value is sign * control * full_scale; a group back at rest is held there or handed back (null), as the
// vehicle says.
const taken = new Set();          // names of the groups the user drives now
view.taken = taken;
function channels(inp) {
  const out = {};
  for (const g of info.controls) {
    const active = g.channels.some((c) => inp[c.control] !== 0);
    if (active) taken.add(g.name);
    else if (g.release === 'hand_back') taken.delete(g.name);
    // a group not taken is sent as null in every request: the server keeps only the newest request
    // while one is in flight, so a hand-back must not ride on one request alone
    for (const c of g.channels) out[c.channel] = taken.has(g.name) ? c.sign * inp[c.control] * c.full_scale : null;
  }
  return out;
}

function drive(inp, now) {
  if (!$('drive').checked && input.touched && !view.driveDeclined) $('drive').checked = true;   // first input: drive
  if (!$('drive').checked || ws.readyState !== 1) return;
  const ch = channels(inp);
  const key = JSON.stringify(Object.entries(ch).map(([n, x]) => [n, x === null ? null : x.toFixed(4)])) + $('takeover').checked;
  if (key === lastSent && now - lastSentAt < 100) return;          // unchanged: every 100 ms (the service holds 1 s)
  lastSent = key; lastSentAt = now;
  ws.send(JSON.stringify({ type: 'drive', seq: ++driveSeq, t_page: performance.now(), takeover: $('takeover').checked, ...ch }));
  view.drive.seq = driveSeq;     // (tests: the service's reply with this seq says when these values were applied)
}

function ack(m) {
  const r = m.reply || {};
  view.drive.last = r;
  if (!r.ok) { view.drive.error = r.error; return; }
  if (m.t_page != null) { keep(rtts, performance.now() - m.t_page); keep(queries, m.query_s * 1e3); }
  view.latency.key_to_model_ms = median(rtts);
  view.latency.key_to_model_max_ms = rtts.length ? Math.max(...rtts) : null;
  view.latency.query_ms = median(queries);
}

$('release').onclick = () => {
  $('drive').checked = false; view.driveDeclined = true; taken.clear();
  ws.send(JSON.stringify({ type: 'drive', seq: ++driveSeq, release: true }));
};
$('drive').onchange = () => { view.driveDeclined = !$('drive').checked; if (!$('drive').checked) $('release').onclick(); };
$('reset').onclick = () => ws.send(JSON.stringify({ type: 'reset' }));
$('camera').onchange = () => scene.setCamera($('camera').value);
$('arrows').onchange = () => { scene.showArrows = $('arrows').checked; };
$('friction').onchange = () => scene.setFriction($('friction').checked);
window.addEventListener('keydown', (e) => {
  if (e.key === ' ' && replay) { e.preventDefault(); $('play').onclick(); }
  if (e.key === 'c') { const o = ['chase', 'cockpit', 'free']; $('camera').value = o[(o.indexOf($('camera').value) + 1) % 3]; scene.setCamera($('camera').value); }
  if (e.key === 't') $('takeover').checked = !$('takeover').checked;
});
window.addEventListener('beforeunload', () => { if ($('drive').checked) ws.send(JSON.stringify({ type: 'drive', release: true })); });

// ---- controller settings ------------------------------------------------------------------------------
function settings() {
  const m = input.map, rows = [];
  const num = (path, v, lo, hi) => `<input type="number" data-p="${path}" value="${v}" min="${lo}" max="${hi}" style="width:4em">`;
  const chk = (path, v) => `<input type="checkbox" data-p="${path}" ${v ? 'checked' : ''}>`;
  rows.push(`<tr><td>steering axis</td><td>${num('steer.axis', m.steer.axis, -1, 15)} invert ${chk('steer.invert', m.steer.invert)}</td></tr>`);
  for (const p of ['throttle', 'brake']) {
    rows.push(`<tr><td>${p} axis</td><td>${num(p + '.axis', m[p].axis, -1, 15)} invert ${chk(p + '.invert', m[p].invert)}
      pedal ${chk(p + '.pedal', m[p].pedal)}</td></tr><tr><td>${p} button</td><td>${num(p + '.button', m[p].button, -1, 31)}</td></tr>`);
  }
  rows.push(`<tr><td>dead zone</td><td>${num('deadzone', m.deadzone, 0, 0.5)}</td></tr>`);
  $('pad-map').innerHTML = rows.join('');
  for (const el of $('pad-map').querySelectorAll('input')) {
    el.onchange = () => {
      const [a, b] = el.dataset.p.split('.');
      const v = el.type === 'checkbox' ? el.checked : Number(el.value);
      if (b) m[a][b] = v; else m[a] = v;
      input.saveMap();
    };
  }
}
$('settings-btn').onclick = () => { settings(); $('settings').hidden = false; };
$('settings-close').onclick = () => { $('settings').hidden = true; };
$('settings-reset').onclick = () => { input.resetMap(); settings(); };

// ---- the frame ----------------------------------------------------------------------------------------
let last = performance.now(), fpsCount = 0, fpsT0 = performance.now(), panelAt = 0;
function frame(now) {
  const dt = Math.min(0.1, (now - last) / 1000); last = now;
  const inp = input.poll(dt);
  if (replay) showReplay(dt);
  else {
    if (!pulling && ws.readyState === 1) { ws.send('{"type":"pull"}'); pulling = true; }
    drive(inp, now);
    if (state) scene.update(state, sensors, dt);
  }
  scene.render(dt);
  view.frames++; fpsCount++;
  if (newState && state) {
    newState = false;
    const t = wall() + clockOffset;                      // this frame, on the server's clock
    keep(screen, (t - stateRx) * 1e3);
    if (simWall !== null) keep(modelScreen, (t - (state.time + simWall)) * 1e3);
    view.latency.server_to_screen_ms = median(screen);
    view.latency.model_to_screen_ms = simWall !== null ? median(modelScreen) : null;
  }
  if (now - fpsT0 >= 1000) { view.fps = fpsCount * 1000 / (now - fpsT0); fpsCount = 0; fpsT0 = now; scene.adapt(view.fps); }
  plots.draw(now);
  if (now - panelAt > 250) { panelAt = now; panel(inp); }
  view.pose = scene.pose;
  view.poses = scene.poses;
  view.ready = true;
  requestAnimationFrame(frame);
}

function panel(inp) {
  const s = status || {}, p = scene.pose || {};
  $('run').textContent = status ? `${s.mode} · ${s.run_state} · t = ${fmt(s.sim_time, 2)} s · ${s.scenario || ''}` +
    (s.message ? ` · ${s.message}` : '') : 'waiting for the service…';
  $('numbers').innerHTML = `<tr><td>speed</td><td class="v">${fmt((p.speed || 0) * 3.6)} km/h</td>
    <td>frame rate</td><td class="v">${fmt(view.fps, 0)} fps</td></tr>
    <tr><td>x, y</td><td class="v">${fmt(p.x)}, ${fmt(p.y)} m</td><td>yaw</td><td class="v">${fmt((p.yaw || 0) * 57.2958)}°</td></tr>`;
  const bar = (x) => `<span class="bar" style="width:${Math.round(60 * Math.abs(x))}px"></span>`;
  $('inputs').innerHTML = `throttle ${bar(inp.throttle)} brake ${bar(inp.brake)} steer ${fmt(inp.steer, 2)}` +
    (input.padName ? ` · pad: ${input.padName.slice(0, 24)}` : '');
  const who = s.drivers || {}, cmd = commands || {};
  $('drivers').innerHTML = '<tr><td><b>input</b></td><td><b>driven by</b></td></tr>' + Object.entries(who).map(([n, w]) =>
    `<tr><td>${n}</td><td class="${w.startsWith('user') ? 'user' : ''}">${w}</td></tr>`).join('') +
    (cmd.source ? `<tr><td>bus commands</td><td>${cmd.source} at ${fmt(cmd.time, 2)} s</td></tr>` : '') +
    (s.user && s.user.lapses ? `<tr><td colspan="2" class="warn">your input lapsed ${s.user.lapses} times: no request ` +
      'reached the service for 1 s (a slow page or network), and the channels went back</td></tr>' : '');
  const us = (x) => x == null ? '–' : `${(x * 1e6).toFixed(0)} us`, ms = (x) => x == null ? '–' : `${(x * 1e3).toFixed(2)} ms`;
  $('health').innerHTML = `<tr><td><b>loop</b></td><td>p50</td><td>p99</td><td>max</td></tr>
    <tr><td>lateness</td><td class="v">${ms(s.lateness_p50)}</td><td class="v">${ms(s.lateness_p99)}</td><td class="v">${ms(s.lateness_max)}</td></tr>
    <tr><td>cpu/step</td><td class="v">${us(s.cpu_p50)}</td><td class="v">${us(s.cpu_p99)}</td><td class="v">${us(s.cpu_max)}</td></tr>
    <tr><td colspan="4">overruns ${s.overruns ?? '–'} · stalls ${s.stalls ?? '–'} · skipped ${s.skipped_steps ?? '–'} · faults: ${
      Object.entries(s.faults || {}).filter(([, v]) => v).map(([k]) => k).join(', ') || 'none'}</td></tr>`;
  const L = view.latency;
  $('latency').innerHTML = `<tr><td><b>latency</b> (median)</td><td></td></tr>
    <tr><td>key → model input (round trip)</td><td class="v">${fmt(L.key_to_model_ms)} ms</td></tr>
    <tr><td>model state → screen</td><td class="v">${L.model_to_screen_ms == null ? 'realtime mode only' : fmt(L.model_to_screen_ms) + ' ms'}</td></tr>
    <tr><td>server → screen</td><td class="v">${fmt(L.server_to_screen_ms)} ms</td></tr>` +
    (view.drive.error ? `<tr><td colspan="2" class="user">${view.drive.error}</td></tr>` : '');
}

// ---- the faults panel: a fault of the catalogue armed live in the service (control ops inject_fault,
// clear_fault; rtsim faults --list). Parameters as "name=value ..." (numbers where they parse), "duration=s"
// and "at=s" too; no trigger: it acts from the service's next step.
let faultSeq = 0;
function faultPanel(kinds, allowed) {
  const sel = $('fault-kind');
  sel.innerHTML = kinds.map(k => `<option value="${k.kind}">${k.kind}</option>`).join('');
  const hint = () => {
    const k = kinds.find(x => x.kind === sel.value);
    if (!k) return;
    $('fault-params').placeholder = [...k.params.filter(p => p.default == null).map(p => p.name + '='), 'duration='].join(' ');
    $('fault-target').placeholder = k.target === 'bus' ? 'bus' : k.target;
    sel.title = k.description;
  };
  sel.onchange = hint;
  hint();
  $('fault-row').hidden = !kinds.length;
  for (const id of ['fault-arm', 'fault-clear']) $(id).disabled = !allowed;
}
function faultArgs(text) {
  const out = {};
  for (const part of text.trim().split(/[\s,]+/)) {
    if (!part) continue;
    const [k, v = ''] = part.split('=');
    const x = Number(v);
    out[k] = v !== '' && Number.isFinite(x) ? x : v;
  }
  return out;
}
function faultAck(r) {
  $('fault-reply').textContent = r.ok ? `${r.fault.id}: ${r.fault.state} (${r.fault.kind} on ${r.fault.target})` : r.error;
  $('fault-reply').className = r.ok ? '' : 'error';
  if (r.ok) $('fault-id').value = r.fault.id;
}
$('fault-arm').onclick = () => {
  let target = $('fault-target').value.trim();
  if (/^\d+$/.test(target)) target = Number(target);
  const args = { id: `view-${Date.now().toString(36)}-${++faultSeq}`, kind: $('fault-kind').value, target, ...faultArgs($('fault-params').value) };
  ws.send(JSON.stringify({ type: 'fault', op: 'inject_fault', args }));
};
$('fault-clear').onclick = () => ws.send(JSON.stringify({ type: 'fault', op: 'clear_fault', args: { id: $('fault-id').value.trim() } }));
