// The user's driving inputs: keyboard (arrows / WASD) and the browser's Gamepad API (gamepads, joysticks,
// steering wheels with pedals). Produces a throttle and a brake in 0..1 and a steering input in -1..1
// (positive: to the right); the page turns them into the vehicle's user channels (app.js).
// The gamepad's mapping (which axis or button is what, inversion, pedal range, dead zone) is set in the
// page's controller dialog and kept in localStorage.
const STORE = 'rtsim.view.gamepad';
export const DEFAULT_MAP = {
  steer: { axis: 0, invert: false },                 // stick x or wheel: -1 left .. 1 right
  throttle: { axis: -1, button: 7, invert: false, pedal: false },   // -1: none; pedal: axis -1..1 -> 0..1
  brake: { axis: -1, button: 6, invert: false, pedal: false },
  deadzone: 0.08,
};

function loadMap() {
  try { return { ...structuredClone(DEFAULT_MAP), ...JSON.parse(localStorage.getItem(STORE) || '{}') }; }
  catch { return structuredClone(DEFAULT_MAP); }
}

function dead(x, dz) {
  const a = Math.abs(x);
  return a <= dz ? 0 : Math.sign(x) * (a - dz) / (1 - dz);
}

export class Input {
  constructor() {
    this.keys = new Set();
    this.throttle = 0; this.brake = 0; this.steer = 0;
    this.touched = false;          // any key or pad input since the page opened
    this.map = loadMap();
    this.pad = null;
    window.addEventListener('keydown', (e) => {
      if (e.target && ['INPUT', 'SELECT', 'TEXTAREA'].includes(e.target.tagName) && e.target.type !== 'checkbox') return;
      const k = e.key.toLowerCase();
      if (['arrowup', 'arrowdown', 'arrowleft', 'arrowright', 'w', 'a', 's', 'd'].includes(k)) {
        this.keys.add(k); this.touched = true; e.preventDefault();
      }
    });
    window.addEventListener('keyup', (e) => this.keys.delete(e.key.toLowerCase()));
    window.addEventListener('blur', () => this.keys.clear());
    window.addEventListener('gamepadconnected', (e) => { this.pad = e.gamepad.index; });
  }

  saveMap() { localStorage.setItem(STORE, JSON.stringify(this.map)); }
  resetMap() { this.map = structuredClone(DEFAULT_MAP); this.saveMap(); }

  gamepad() {
    const pads = navigator.getGamepads ? navigator.getGamepads() : [];
    if (this.pad !== null && pads[this.pad]) return pads[this.pad];
    for (const p of pads) if (p) { this.pad = p.index; return p; }
    return null;
  }

  pedal(gp, m) {
    let x = 0;
    if (m.axis >= 0 && m.axis < gp.axes.length) {
      x = gp.axes[m.axis];
      if (m.invert) x = -x;
      if (m.pedal) x = (x + 1) / 2;                     // a wheel's pedal: -1 released .. 1 pressed
      x = Math.max(0, x);
    }
    if (m.button >= 0 && m.button < gp.buttons.length) x = Math.max(x, gp.buttons[m.button].value);
    return Math.min(1, dead(x, this.map.deadzone));
  }

  // one frame of dt s: keys ramp like pedals and a wheel would (throttle up in 0.5 s, steer in 0.7 s)
  poll(dt) {
    const k = this.keys;
    const up = k.has('arrowup') || k.has('w'), down = k.has('arrowdown') || k.has('s');
    const left = k.has('arrowleft') || k.has('a'), right = k.has('arrowright') || k.has('d');
    const ramp = (x, target, rise, fall) => x < target ? Math.min(target, x + rise * dt) : Math.max(target, x - fall * dt);
    this.throttle = ramp(this.throttle, up ? 1 : 0, 2, 4);
    this.brake = ramp(this.brake, down ? 1 : 0, 3, 5);
    const target = (right ? 1 : 0) - (left ? 1 : 0);
    this.steer = this.steer < target ? Math.min(target, this.steer + 1.5 * dt * (this.steer < 0 ? 2 : 1))
      : Math.max(target, this.steer - 1.5 * dt * (this.steer > 0 ? 2 : 1));
    const gp = this.gamepad();
    this.padName = gp ? gp.id : null;
    if (gp) {
      const m = this.map;
      let s = m.steer.axis >= 0 && m.steer.axis < gp.axes.length ? gp.axes[m.steer.axis] : 0;
      if (m.steer.invert) s = -s;
      s = dead(s, m.deadzone);
      const thr = this.pedal(gp, m.throttle), brk = this.pedal(gp, m.brake);
      if (s !== 0 || thr > 0 || brk > 0) this.touched = true;
      if (!(up || down || left || right)) {            // the keyboard wins while a key is held
        this.throttle = thr; this.brake = brk; this.steer = s;
      }
    }
    return { throttle: this.throttle, brake: this.brake, steer: this.steer };
  }
}
