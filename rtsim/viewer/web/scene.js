// The 3D scene: road, vehicle, cameras. World axes as the state channels (ISO 8855: x forward, y left,
// z up; metres, radians). A vehicle is posed from one state sample (and the latest sensor sample for a
// car's road-wheel steer and spin angles): update(state, sensors).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

THREE.Object3D.DEFAULT_UP.set(0, 0, 1);

function gridTexture() {
  const c = document.createElement('canvas');
  c.width = c.height = 256;
  const g = c.getContext('2d');
  g.fillStyle = '#6d6f72'; g.fillRect(0, 0, 256, 256);
  g.strokeStyle = '#83868a'; g.lineWidth = 2;
  for (let i = 0; i <= 256; i += 51.2) { g.beginPath(); g.moveTo(i, 0); g.lineTo(i, 256); g.stroke();
    g.beginPath(); g.moveTo(0, i); g.lineTo(256, i); g.stroke(); }
  g.strokeStyle = '#e8e8e8'; g.lineWidth = 4; g.strokeRect(0, 0, 256, 256);
  const t = new THREE.CanvasTexture(c);
  t.wrapS = t.wrapT = THREE.RepeatWrapping;
  t.anisotropy = 4;
  return t;
}

function frictionColour(mu, lo, hi) {
  const f = hi > lo ? (mu - lo) / (hi - lo) : 0.5;        // low friction red, high green
  return new THREE.Color().setHSL(0.33 * Math.min(1, Math.max(0, f)), 0.75, 0.45);
}

function softwareGL() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2');
    const ext = gl && gl.getExtension('WEBGL_debug_renderer_info');
    const name = ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : '';
    gl && gl.getExtension('WEBGL_lose_context')?.loseContext();
    return /swiftshader|llvmpipe|software/i.test(name);
  } catch { return false; }
}

const TILE = 5.0;         // m per grid texture tile
const GROUND = 400.0;     // m, side of the ground plane that follows the vehicle

export class Scene3D {
  constructor(canvas) {
    this.canvas = canvas;
    // software rendering (no GPU: SwiftShader) pays for every pixel: no multisampling there, and the
    // drawing buffer starts at 3/4 of the window and scales down while the frame rate is below 40/s (up
    // again above 57/s)
    this.software = softwareGL();
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: !this.software, powerPreference: 'high-performance' });
    this.renderer.setPixelRatio(1);
    this.scale = this.software ? 0.75 : 1.0;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color('#9fc3e6');
    this.scene.fog = new THREE.Fog('#9fc3e6', 120, 260);
    this.scene.add(new THREE.HemisphereLight('#ffffff', '#556655', 1.6));
    const sun = new THREE.DirectionalLight('#ffffff', 1.6);
    sun.position.set(-30, 20, 60);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(55, 1, 0.05, 600);
    this.cameraMode = 'chase';
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enabled = false;
    this.showArrows = false;
    this.showFriction = false;
    this.vehicle = null;             // the one the cameras follow (a replay's first recording)
    this.others = [];                // a second recording's vehicle, side by side
    this.pose = null;
    this.poses = [];
    this._chase = null;
    this._tmp = new THREE.Vector3();
    this._ray = new THREE.Raycaster();
    window.addEventListener('resize', () => this.resize());
    this.resize();
  }

  // called once a second with the frame rate measured
  adapt(fps) {
    const s = fps < 40 ? Math.max(0.4, this.scale * 0.8) : fps > 57 ? Math.min(1, this.scale * 1.1) : this.scale;
    if (Math.abs(s - this.scale) > 1e-3) { this.scale = s; this.resize(); }
  }

  resize() {
    const w = this.canvas.clientWidth, h = this.canvas.clientHeight;
    this.renderer.setSize(Math.round(w * this.scale), Math.round(h * this.scale), false);
    this.camera.aspect = w / Math.max(1, h);
    // the panels cover the window's right and left edges: the view's centre a little left of the middle
    this.camera.setViewOffset(w, h, 0.08 * w, 0, w, h);
    this.camera.updateProjectionMatrix();
  }

  // ---- road -------------------------------------------------------------------------------------------
  build(info) {
    this.info = info;
    this.road = info.road;
    this.buildRoad(info.road);
    this.vehicle = this.buildVehicle(info, '#c0282d');
    this.scene.add(this.vehicle.group);
    this.arrows = [];
    for (const w of this.vehicle.wheels) {
      const a = new THREE.ArrowHelper(new THREE.Vector3(1, 0, 0), new THREE.Vector3(), 1, '#ffcc00', 0.25, 0.15);
      a.visible = false;
      this.scene.add(a);
      this.arrows.push(a);
    }
  }

  buildVehicle(info, colour) {
    return info.kind === 'two_wheeler' ? this.buildTwoWheeler(info.shape, colour) : this.buildCar(info.shape, colour);
  }

  // a second vehicle (a second recording played beside the first)
  addVehicle(info, colour) {
    const v = this.buildVehicle(info, colour);
    this.others.push(v);
    this.scene.add(v.group);
  }

  buildRoad(road) {
    const tex = gridTexture();
    tex.repeat.set(GROUND / TILE, GROUND / TILE);
    const ground = new THREE.Mesh(new THREE.PlaneGeometry(GROUND, GROUND),
      new THREE.MeshLambertMaterial({ map: tex }));
    this.ground = ground;
    this.scene.add(ground);
    if (road.type === 'grade') {
      const h = road.heading, g = road.grade;
      const n = new THREE.Vector3(-g * Math.cos(h), -g * Math.sin(h), 1).normalize();
      ground.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), n);
    } else if (road.type === 'mesh') {
      const v = road.vertices, t = road.triangles, mu = road.mu;
      const pos = new Float32Array(t.length * 3), col = new Float32Array(t.length * 3);
      const lo = Math.min(...mu), hi = Math.max(...mu);
      const asphalt = new THREE.Color('#5c5f63');
      this._muColours = [];
      for (let k = 0; k < t.length / 3; k++) {
        const c = frictionColour(mu[k], lo - 0.05, hi + 0.05);
        this._muColours.push(c);
        for (let j = 0; j < 3; j++) {
          const i = t[3 * k + j];
          pos.set([v[3 * i], v[3 * i + 1], v[3 * i + 2]], 9 * k + 3 * j);
          col.set([asphalt.r, asphalt.g, asphalt.b], 9 * k + 3 * j);
        }
      }
      const geo = new THREE.BufferGeometry();
      geo.setAttribute('position', new THREE.BufferAttribute(pos, 3));
      geo.setAttribute('color', new THREE.BufferAttribute(col, 3));
      geo.computeVertexNormals();
      geo.computeBoundingSphere();
      this.meshRoad = new THREE.Mesh(geo, new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }));
      this.scene.add(this.meshRoad);
      let zmin = Infinity;
      for (let i = 2; i < v.length; i += 3) zmin = Math.min(zmin, v[i]);
      this.groundZ = zmin - 0.3;                 // the plane under and around the survey
      ground.material.color.set('#8a9a7a');
      const wallMat = new THREE.MeshLambertMaterial({ color: '#d9d4c7' });
      for (const b of road.buildings || []) {     // blocks from the file beside the survey
        const box = new THREE.Mesh(new THREE.BoxGeometry(b.length, b.width, b.height + 0.3), wallMat);
        box.position.set(b.x, b.y, b.z - 0.3 + (b.height + 0.3) / 2);
        box.rotation.z = b.yaw_deg * Math.PI / 180;
        this.scene.add(box);
      }
    }
  }

  setFriction(on) {
    this.showFriction = on;
    if (!this.meshRoad) return;
    const col = this.meshRoad.geometry.attributes.color, asphalt = new THREE.Color('#5c5f63');
    for (let k = 0; k < this._muColours.length; k++) {
      const c = on ? this._muColours[k] : asphalt;
      for (let j = 0; j < 3; j++) col.setXYZ(3 * k + j, c.r, c.g, c.b);
    }
    col.needsUpdate = true;
  }

  // height of the road under (x, y), m
  roadHeight(x, y) {
    const r = this.road;
    if (r.type === 'flat') return r.height;
    if (r.type === 'grade') {
      const o = r.origin;
      return o[2] + r.grade * ((x - o[0]) * Math.cos(r.heading) + (y - o[1]) * Math.sin(r.heading));
    }
    this._ray.set(this._tmp.set(x, y, 1e3), new THREE.Vector3(0, 0, -1));
    const hit = this._ray.intersectObject(this.meshRoad, false);
    return hit.length ? hit[0].point.z : this.groundZ;
  }

  // ---- vehicles ---------------------------------------------------------------------------------------
  wheelMesh(radius, width) {
    const spin = new THREE.Group();
    const tyre = new THREE.Mesh(new THREE.CylinderGeometry(radius, radius, width, 28, 1),
      new THREE.MeshLambertMaterial({ color: '#1d1d1f' }));               // (the cylinder's axis is y: the axle)
    spin.add(tyre);
    const rim = new THREE.Mesh(new THREE.BoxGeometry(radius * 1.3, width * 1.05, radius * 0.22),
      new THREE.MeshLambertMaterial({ color: '#c9ccd1' }));               // a spoke: shows the spin
    spin.add(rim);
    const rim2 = rim.clone(); rim2.rotation.y = Math.PI / 2; spin.add(rim2);
    return spin;
  }

  buildCar(s, colour) {
    const group = new THREE.Group();
    const b = s.body;
    const paint = new THREE.MeshLambertMaterial({ color: colour });
    const len = b.x_front - b.x_rear, lowH = 0.5;
    const lower = new THREE.Mesh(new THREE.BoxGeometry(len, b.width, lowH), paint);
    lower.position.set((b.x_front + b.x_rear) / 2, 0, b.z_floor + lowH / 2 + 0.05);
    group.add(lower);
    const cabin = new THREE.Mesh(new THREE.BoxGeometry(len * 0.5, b.width * 0.86, 0.45),
      new THREE.MeshLambertMaterial({ color: '#36414d' }));
    cabin.position.set(b.x_rear + len * 0.42, 0, b.z_floor + lowH + 0.05 + 0.225);
    group.add(cabin);
    const wheels = [];
    for (const c of ['fl', 'fr', 'rl', 'rr']) {
      const p = s.wheels[c];
      const mount = new THREE.Group();          // at the design wheel centre; moves with the suspension
      mount.position.set(p[0], p[1], p[2]);
      const steer = new THREE.Group();
      const spin = this.wheelMesh(s.wheel_radius, s.wheel_width);
      steer.add(spin); mount.add(steer); group.add(mount);
      wheels.push({ corner: c, design: new THREE.Vector3(p[0], p[1], p[2]), mount, steer, spin, angle: 0 });
    }
    const eye = new THREE.Object3D();        // the driver's eyes: behind the cabin's front, above the hood
    eye.position.set(cabin.position.x + len * 0.25 - 0.3, s.wheels.fl[1] * 0.45, b.z_floor + 1.1);
    group.add(eye);
    cabin.userData.hideInCockpit = true;
    return { kind: 'car', group, wheels, eye, shape: s };
  }

  buildTwoWheeler(s, colour) {
    const group = new THREE.Group();                 // origin: the swingarm pivot, rear frame axes
    const paint = new THREE.MeshLambertMaterial({ color: colour === '#c0282d' ? '#1f5fbf' : colour });
    const dark = new THREE.MeshLambertMaterial({ color: '#2a2a2e' });
    const head = new THREE.Vector3(...s.steer_head), cg = new THREE.Vector3(...s.cg);
    const frameLen = head.clone().setY(0).length();
    const frame = new THREE.Mesh(new THREE.BoxGeometry(frameLen + 0.2, 0.22, 0.28), paint);
    frame.position.set(head.x / 2, 0, (head.z + cg.z) / 2);
    frame.rotation.y = -Math.atan2(head.z - cg.z, head.x) * 0.5;
    group.add(frame);
    const seat = new THREE.Mesh(new THREE.BoxGeometry(0.6, 0.26, 0.1), dark);
    seat.position.set(cg.x - 0.15, 0, cg.z + 0.25);
    group.add(seat);
    const r = new THREE.Vector3(...(s.rider || s.cg));   // the rider's centre (the cockpit camera's reference)
    if (s.rider) {                       // (a machine without a rider, the benchmark bicycle: none drawn)
      const rider = new THREE.Mesh(new THREE.BoxGeometry(0.32, 0.4, 0.62), new THREE.MeshLambertMaterial({ color: '#e0a030' }));
      rider.position.set(r.x, 0, r.z + 0.05);
      rider.rotation.y = 0.45;
      group.add(rider);
      const helmet = new THREE.Mesh(new THREE.SphereGeometry(0.14, 16, 12), dark);
      helmet.position.set(r.x + 0.22, 0, r.z + 0.45);
      group.add(helmet);
    }
    const rw = new THREE.Vector3(...s.rear_wheel);
    const swing = new THREE.Mesh(new THREE.BoxGeometry(rw.length(), 0.06, 0.06), dark);
    swing.position.set(rw.x / 2, 0.08, rw.z / 2);
    swing.rotation.y = Math.atan2(-rw.z, rw.x) + Math.PI;
    group.add(swing);
    const rearMount = new THREE.Group(); rearMount.position.copy(rw);
    const rearSteer = new THREE.Group(); rearMount.add(rearSteer);
    const rearSpin = this.wheelMesh(s.rear_radius, 0.18); rearSteer.add(rearSpin);
    group.add(rearMount);
    // the front assembly turns about the steering axis through the head
    const axis = new THREE.Vector3(...s.steer_axis).normalize();
    const fork = new THREE.Group(); fork.position.copy(head); group.add(fork);
    const fw = new THREE.Vector3(...s.front_wheel).sub(head);           // front wheel centre from the head
    const frontMount = new THREE.Group(); frontMount.position.copy(fw); fork.add(frontMount);
    const frontSpin = this.wheelMesh(s.front_radius, 0.14); frontMount.add(frontSpin);
    const tubeLen = fw.length();
    for (const y of [0.1, -0.1]) {
      const tube = new THREE.Mesh(new THREE.CylinderGeometry(0.025, 0.025, tubeLen, 8), new THREE.MeshLambertMaterial({ color: '#b8bcc2' }));
      tube.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), fw.clone().normalize());
      tube.position.copy(fw.clone().multiplyScalar(0.5)).setY(y);
      fork.add(tube);
    }
    const bar = new THREE.Mesh(new THREE.BoxGeometry(0.05, 0.7, 0.04), dark);
    bar.position.set(-0.05, 0, 0.05); fork.add(bar);
    const eye = new THREE.Object3D(); eye.position.set(r.x + 0.3, 0, r.z + 0.5); group.add(eye);
    return { kind: 'two_wheeler', group, fork, axis, frontMount, frontDesign: fw.clone(), eye, shape: s,
             wheels: [{ corner: 'front', spin: frontSpin, mount: frontMount, angle: 0 },
                      { corner: 'rear', spin: rearSpin, mount: rearMount, angle: 0 }] };
  }

  // ---- one sample ---------------------------------------------------------------------------------------
  // vehicle k (0: the followed one) posed from one state sample
  update(st, sens, dt, k = 0) {
    const v = k === 0 ? this.vehicle : this.others[k - 1];
    if (!v || !st) return;
    const g = v.group;
    g.position.set(st.pos_x, st.pos_y, st.pos_z);
    g.rotation.set(st.roll_angle, st.pitch_angle, st.yaw_angle, 'ZYX');
    g.updateMatrixWorld(true);
    this.poses[k] = { t: st.time, x: st.pos_x, y: st.pos_y, z: st.pos_z, roll: st.roll_angle, pitch: st.pitch_angle,
                      yaw: st.yaw_angle, speed: st.speed };
    const arrows = k === 0;
    if (v.kind === 'car') this.updateCar(v, st, sens || {}, dt, arrows);
    else this.updateTwoWheeler(v, st, dt, arrows);
    if (k !== 0) return;
    this.pose = this.poses[0];
    // the ground plane follows the vehicle (in whole tiles, so the grid stays put on the road)
    const gx = Math.round(st.pos_x / TILE) * TILE, gy = Math.round(st.pos_y / TILE) * TILE;
    this.ground.position.set(gx, gy, this.road.type === 'mesh' ? this.groundZ : this.roadHeight(gx, gy) - 0.002);
  }

  updateCar(v, st, sens, dt, arrows) {
    const s = v.shape, inv = new THREE.Matrix4().copy(v.group.matrixWorld).invert();
    for (const w of v.wheels) {
      // the wheel stands on the road: its centre at the road height + the loaded radius, in the body frame
      const p = w.design.clone().applyMatrix4(v.group.matrixWorld);
      const fz = st['tyre_fz_' + w.corner];
      const r = s.wheel_radius - Math.max(0, Number.isFinite(fz) ? fz : 0) / s.tyre_kz;
      p.z = this.roadHeight(p.x, p.y) + r;
      const local = p.applyMatrix4(inv);
      w.mount.position.z = Math.min(w.design.z + 0.12, Math.max(w.design.z - 0.12, local.z));
      const steer = sens['steer_angle_' + w.corner];
      w.steer.rotation.z = Number.isFinite(steer) ? steer : 0;
      const ang = sens['wheel_angle_' + w.corner];
      if (Number.isFinite(ang)) w.angle = ang;
      else w.angle += (st['wheel_speed_' + w.corner] || 0) * dt;
      w.spin.rotation.y = w.angle;
    }
    if (arrows) this.updateArrows(v, st, ['fl', 'fr', 'rl', 'rr']);
  }

  updateTwoWheeler(v, st, dt, arrows) {
    v.fork.quaternion.setFromAxisAngle(v.axis, st.steer_angle || 0);
    // fork travel shortens the fork along the steering axis (the wheel moves towards the head)
    v.frontMount.position.copy(v.frontDesign).addScaledVector(v.axis, st.fork_travel || 0);
    const [f, r] = v.wheels;
    f.angle = Number.isFinite(st.wheel_angle_front) ? st.wheel_angle_front : f.angle + (st.wheel_speed_front || 0) * dt;
    r.angle = Number.isFinite(st.wheel_angle_rear) ? st.wheel_angle_rear : r.angle + (st.wheel_speed_rear || 0) * dt;
    f.spin.rotation.y = f.angle;
    r.spin.rotation.y = r.angle;
    if (arrows) this.updateArrows(v, st, ['front', 'rear']);
  }

  updateArrows(v, st, corners) {
    corners.forEach((c, i) => {
      const a = this.arrows[i];
      a.visible = this.showArrows;
      if (!a.visible) return;
      const fx = st['tyre_fx_' + c] || 0, fy = st['tyre_fy_' + c] || 0;
      const wheel = v.wheels[i].mount;
      const p = new THREE.Vector3(); wheel.getWorldPosition(p);
      p.z = this.roadHeight(p.x, p.y) + 0.05;
      const cy = Math.cos(st.yaw_angle), sy = Math.sin(st.yaw_angle);
      const d = new THREE.Vector3(fx * cy - fy * sy, fx * sy + fy * cy, 0);
      const len = d.length() / 2000;                    // 1 m per 2 kN
      a.position.copy(p);
      if (len > 1e-3) { a.setDirection(d.normalize()); a.setLength(len, Math.min(0.3, 0.4 * len), 0.12); }
      else a.visible = false;
    });
  }

  // ---- cameras --------------------------------------------------------------------------------------
  setCamera(mode) {
    this.cameraMode = mode;
    this.controls.enabled = mode === 'free';
    this._chase = null;
    if (mode === 'free' && this.pose) {
      this.controls.target.set(this.pose.x, this.pose.y, this.pose.z);
    }
  }

  render(dt) {
    const v = this.vehicle, p = this.pose;
    if (v && p) {
      const cam = this.camera;
      for (const o of v.group.children) if (o.userData.hideInCockpit) o.visible = this.cameraMode !== 'cockpit';
      if (this.cameraMode === 'chase') {
        const back = v.kind === 'car' ? 8.5 : 5.5, up = v.kind === 'car' ? 3.0 : 2.0;
        const want = new THREE.Vector3(p.x - back * Math.cos(p.yaw), p.y - back * Math.sin(p.yaw), p.z + up);
        if (!this._chase) this._chase = want.clone();
        this._chase.lerp(want, Math.min(1, 4 * dt));    // a little lag: the car's yaw shows
        cam.position.copy(this._chase);
        cam.up.set(0, 0, 1);
        cam.lookAt(p.x, p.y, p.z + 0.6);
      } else if (this.cameraMode === 'cockpit') {
        v.eye.getWorldPosition(cam.position);
        const fwd = new THREE.Vector3(1, 0, -0.05).applyQuaternion(v.group.quaternion);
        cam.up.set(0, 0, 1).applyQuaternion(v.group.quaternion);
        cam.lookAt(cam.position.clone().add(fwd));
      } else {
        const t = this.controls.target, d = new THREE.Vector3(p.x, p.y, p.z).sub(t);
        t.add(d); cam.position.add(d);                  // the orbit follows the vehicle
        this.controls.update();
      }
    }
    this.renderer.render(this.scene, this.camera);
  }
}
