// Live plots (uPlot): the channels the user picks (state and sensor channels, against simulation time)
// and the loop's health (lateness and CPU per step from the status). Samples go into fixed-size rings;
// the charts are redrawn a few times a second, not at every frame.
import uPlot from 'uplot';

const WINDOW = 20;          // s of simulation time shown
const CAP = 4000;           // samples kept per series
const PALETTE = ['#c0282d', '#1f5fbf', '#2a9d4a', '#b07a00', '#7a3fb0', '#0a8a8a'];

class Series {
  constructor() { this.t = []; this.v = []; }
  push(t, v) {
    if (this.t.length && t < this.t[this.t.length - 1]) { this.t.length = 0; this.v.length = 0; }   // a reset
    this.t.push(t); this.v.push(v);
    if (this.t.length > CAP) { this.t.splice(0, this.t.length - CAP); this.v.splice(0, this.v.length - CAP); }
  }
}

export class Plots {
  constructor(el, healthEl, picker) {
    this.el = el; this.healthEl = healthEl; this.picker = picker;
    this.series = new Map();            // channel -> Series
    this.units = {};
    this.picked = [];
    this.health = { t: [], lat: [], cpu50: [], cpu99: [] };
    this.dirty = false;
    this.lastDraw = 0;
  }

  init(info, defaults) {
    const ch = info.channels || {};
    const opts = [];
    for (const group of ['state', 'sensors']) {
      for (const [name, unit] of ch[group] || []) {        // (name, unit, meaning)
        if (this.units[name] !== undefined) continue;
        this.units[name] = unit;
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
      axes: [{}, { label: 'us / ms', size: 50 }],
      series: [{ label: 't [s]' }, { label: 'lateness p99 [ms]', stroke: '#c0282d' },
               { label: 'cpu/step p50 [us]', stroke: '#1f5fbf' }, { label: 'cpu/step p99 [us]', stroke: '#2a9d4a' }],
    }, [[], [], [], []], this.healthEl);
  }

  pick(names) {
    this.picked = names;
    for (const o of this.picker.options) o.selected = names.includes(o.value);
    for (const n of names) if (!this.series.has(n)) this.series.set(n, new Series());
    if (this.chart) this.chart.destroy();
    this.chart = new uPlot({
      width: 500, height: 170, legend: { live: false }, scales: { x: { time: false } },
      axes: [{}, { size: 50 }],
      series: [{ label: 't [s]' }, ...names.map((n, i) => ({ label: `${n} [${this.units[n]}]`, stroke: PALETTE[i % 6] }))],
    }, this.data(), this.el);
  }

  push(samples) {                        // state or sensor samples (objects with time and channels)
    for (const s of samples) {
      for (const n of this.picked) {
        if (n in s) this.series.get(n).push(s.time, s[n] === null ? NaN : s[n]);
      }
    }
    if (samples.length) this.dirty = true;
  }

  pushStatus(st) {
    const h = this.health;
    if (h.t.length && st.sim_time < h.t[h.t.length - 1]) for (const k in h) h[k].length = 0;
    h.t.push(st.sim_time);
    h.lat.push(st.lateness_p99 == null ? NaN : st.lateness_p99 * 1e3);
    h.cpu50.push(st.cpu_p50 == null ? NaN : st.cpu_p50 * 1e6);
    h.cpu99.push(st.cpu_p99 == null ? NaN : st.cpu_p99 * 1e6);
    if (h.t.length > 600) for (const k in h) h[k].splice(0, h[k].length - 600);
    this.healthDirty = true;
  }

  data() {
    // one time base: the first picked series' (state channels share it; sensors are more frequent)
    if (!this.picked.length) return [[]];
    const base = this.series.get(this.picked[0]);
    const t = base.t, t0 = t.length ? t[t.length - 1] - WINDOW : 0;
    let i0 = t.findIndex((x) => x >= t0); if (i0 < 0) i0 = t.length;
    const out = [t.slice(i0)];
    for (const n of this.picked) {
      const s = this.series.get(n);
      if (s === base) { out.push(s.v.slice(i0)); continue; }
      const vals = []; let j = 0;              // sample-and-hold onto the base's times
      for (const x of out[0]) { while (j + 1 < s.t.length && s.t[j + 1] <= x) j++; vals.push(s.t.length ? s.v[j] : NaN); }
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
