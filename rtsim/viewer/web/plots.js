// Live plots (uPlot): the channels the user picks (state and sensor channels, against simulation time)
// and the loop's health (lateness and CPU per step from the status). Samples go into fixed-size rings;
// the charts are redrawn a few times a second, not at every frame.
import uPlot from 'uplot';

const WINDOW = 20;          // s of simulation time shown
const CAP = 12000;          // samples kept per series (live; a replay keeps all)
const PALETTE = ['#c0282d', '#1f5fbf', '#2a9d4a', '#b07a00', '#7a3fb0', '#0a8a8a'];

class Series {
  constructor(cap) { this.t = []; this.v = []; this.cap = cap; }
  push(t, v) {
    if (this.t.length && t < this.t[this.t.length - 1]) { this.t.length = 0; this.v.length = 0; }   // a reset
    this.t.push(t); this.v.push(v);
    if (this.t.length > this.cap) { this.t.splice(0, this.t.length - this.cap); this.v.splice(0, this.v.length - this.cap); }
  }
}

// Tick labels of a value axis: as many decimals as the tick step needs (uPlot's default formatter keeps at
// most three, so ticks 0.0001 apart all read "0"), and an SI prefix (p n µ m k M G) where plain decimals
// would be long: the largest tick below 0.01 or from 100 000 on. Consecutive ticks always read differently.
const PREFIX = { '-12': 'p', '-9': 'n', '-6': 'µ', '-3': 'm', '3': 'k', '6': 'M', '9': 'G' };
function decimals(x) {                 // decimals that write x (> 0) exactly, to 1 ppm
  for (let d = 0; d < 12; d++) { const y = x * 10 ** d; if (Math.abs(y - Math.round(y)) <= 1e-6 * y) return d; }
  return 12;
}
export function tickLabels(splits, incr) {
  const vals = splits.filter((v) => v != null && Number.isFinite(v));
  if (!(incr > 0)) incr = vals.length > 1 ? Math.min(...vals.slice(1).map((v, k) => Math.abs(v - vals[k])).filter((d) => d > 0)) : 0;
  const big = Math.max(0, ...vals.map(Math.abs));
  if (!(big > 0) || !(incr > 0)) return splits.map((v) => (v == null ? '' : String(v)));
  let e = 0;
  if (big < 1e-2 || big >= 1e5) e = Math.max(-12, Math.min(9, 3 * Math.floor(Math.log10(big) / 3)));
  const scale = 10 ** e, d = decimals(incr / scale), pre = PREFIX[String(e)] || '';
  return splits.map((v) => (v == null ? '' : (Math.abs(v) < 1e-6 * incr ? 0 : v / scale).toFixed(d) + pre));
}
const axisValues = (u, splits, _axis, _space, incr) => tickLabels(splits, incr);
// the value axis as wide as its longest label (about 7 px a character at the axis' 12 px font) plus the ticks
const axisSize = (u, values) => Math.max(40, 16 + 7 * Math.max(0, ...(values || []).map((s) => String(s).length)));

function firstAtOrAfter(t, x) {      // index of the first t[i] >= x (t ascending)
  let lo = 0, hi = t.length;
  while (lo < hi) { const m = (lo + hi) >> 1; if (t[m] < x) lo = m + 1; else hi = m; }
  return lo;
}

export class Plots {
  constructor(el, healthEl, picker) {
    this.el = el; this.healthEl = healthEl; this.picker = picker;
    this.series = new Map();            // channel -> Series
    this.units = {};
    this.group = {};                    // channel -> the topic it is plotted from (state, else sensors)
    this.picked = [];
    this.health = { t: [], lat: [], cpu50: [], cpu99: [] };
    this.dirty = false;
    this.lastDraw = 0;
    this.suffixes = [''];              // one per source: '' and ' (B)' for a second recording
    this.until = null;                 // a replay: the time shown last (live: the newest sample)
    this.cap = CAP;
  }

  init(info, defaults) {
    const ch = info.channels || {};
    const opts = [];
    for (const group of ['state', 'sensors']) {
      for (const [name, unit] of ch[group] || []) {        // (name, unit, meaning)
        if (this.units[name] !== undefined) continue;      // (a sensor of a state channel's name: the state's)
        this.units[name] = unit;
        this.group[name] = group;
        opts.push(`<option value="${name}">${name} [${unit}]</option>`);
      }
    }
    this.picker.innerHTML = opts.join('');
    const saved = JSON.parse(localStorage.getItem('rtsim.view.plot.' + info.kind) || 'null');
    this.pick((saved || defaults).filter((n) => n in this.units));
    this.picker.addEventListener('change', () => {
      const names = [...this.picker.selectedOptions].map((o) => o.value).slice(0, 6);
      localStorage.setItem('rtsim.view.plot.' + info.kind, JSON.stringify(names));
      this.pick(names);
    });
    this.healthPlot = new uPlot({
      width: 500, height: 110, title: 'loop health', legend: { live: false },
      scales: { x: { time: false } },
      axes: [{ values: axisValues }, { label: 'us / ms', values: axisValues, size: (u, v) => 20 + axisSize(u, v) }],
      series: [{ label: 't [s]' }, { label: 'lateness p99 [ms]', stroke: '#c0282d' },
               { label: 'cpu/step p50 [us]', stroke: '#1f5fbf' }, { label: 'cpu/step p99 [us]', stroke: '#2a9d4a' }],
    }, [[], [], [], []], this.healthEl);
  }

  pick(names) {
    this.picked = names;
    for (const o of this.picker.options) o.selected = names.includes(o.value);
    this.keys = [];
    for (const n of names) for (const x of this.suffixes) this.keys.push(n + x);
    for (const k of this.keys) if (!this.series.has(k)) this.series.set(k, new Series(this.cap));
    if (this.refill) this.refill();           // a replay: the picked channels from its samples
    if (this.chart) this.chart.destroy();
    this.chart = new uPlot({
      width: 500, height: 170, legend: { live: false }, scales: { x: { time: false } },
      axes: [{ values: axisValues }, { values: axisValues, size: axisSize }],
      series: [{ label: 't [s]' }, ...this.keys.map((k, i) => {
        const n = k.replace(' (B)', '');
        return { label: `${k} [${this.units[n]}]`, stroke: PALETTE[this.picked.indexOf(n) % 6], dash: k.endsWith('(B)') ? [6, 4] : undefined };
      })],
    }, this.data(), this.el);
  }

  push(samples, source = 0, group = 'state') {   // state or sensor samples (objects with time and channels)
    const x = this.suffixes[source] || '';
    const names = this.picked.filter((n) => this.group[n] === group);
    for (const s of samples) {
      for (const n of names) {
        if (n in s) this.series.get(n + x).push(s.time, s[n]);     // (null: a gap)
      }
    }
    if (samples.length) this.dirty = true;
  }

  pushStatus(st) {
    const h = this.health;
    if (h.t.length && st.sim_time < h.t[h.t.length - 1]) for (const k in h) h[k].length = 0;
    h.t.push(st.sim_time);
    h.lat.push(st.lateness_p99 == null ? null : st.lateness_p99 * 1e3);
    h.cpu50.push(st.cpu_p50 == null ? null : st.cpu_p50 * 1e6);
    h.cpu99.push(st.cpu_p99 == null ? null : st.cpu_p99 * 1e6);
    const keep = this.cap > CAP ? 1e6 : 600;              // live: the last minute; a replay: all
    if (h.t.length > keep) for (const k in h) h[k].splice(0, h[k].length - keep);
    this.healthDirty = true;
  }

  data() {
    // one time base: the first picked series' (state channels share it; sensors are more frequent)
    if (!this.keys || !this.keys.length) return [[]];
    const base = this.series.get(this.keys[0]);
    const t = base.t, end = this.until ?? (t.length ? t[t.length - 1] : 0);
    const i0 = firstAtOrAfter(t, end - WINDOW), i1 = firstAtOrAfter(t, end + 1e-9);
    const out = [t.slice(i0, i1)];
    for (const k of this.keys) {
      const s = this.series.get(k);
      if (s === base) { out.push(s.v.slice(i0, i1)); continue; }
      const vals = []; let j = Math.max(0, firstAtOrAfter(s.t, out[0][0] ?? 0) - 1);   // sample-and-hold onto the base's times
      for (const x of out[0]) { while (j + 1 < s.t.length && s.t[j + 1] <= x) j++; vals.push(s.t.length && s.t[j] <= x ? s.v[j] : null); }
      out.push(vals);
    }
    return out;
  }

  draw(now) {
    if (now - this.lastDraw < 150) return;      // ~7 redraws a second
    this.lastDraw = now;
    if (this.dirty && this.chart) { this.chart.setData(this.data()); this.dirty = false; }
    if (this.healthDirty) {
      const h = this.health;
      this.healthPlot.setData([h.t.slice(), h.lat.slice(), h.cpu50.slice(), h.cpu99.slice()]);
      this.healthDirty = false;
    }
  }
}
