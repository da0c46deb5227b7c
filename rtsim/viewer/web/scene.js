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

// a geometry of separate triangles (flat colour each): vertices (x, y, z flat), triangles (3 indices each),
// colourOf(k) the colour of triangle k
function triangleSoup(v, t, colourOf) {
  const pos = new Float32Array(t.length * 3), col = new Float32Array(t.length * 3);
  for (let k = 0; k < t.length / 3; k++) {
    const c = colourOf(k);
    for (let j = 0; j < 3; j++) {
      const i = t[3 * k + j];
      pos.set([v[3 * i], v[3 * i + 1], v[3 * i + 2]], 9 * k + 3 * j);
      col.set([c.r, c.g, c.b], 9 * k + 3 * j);
    }
  }
  const geo = new THREE.BufferGeometry();
  geo.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  geo.setAttribute('color', new THREE.BufferAttribute(col, 3));
  return geo;
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

const DEFAULT_COLOUR = '#c0282d';   // the followed vehicle's paint (a drawing may choose its own)
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
    // a new size clears the canvas: draw the scene again at once, or the page shows its bare background
    // until the next frame (a screenshot or a slow frame in between sees no road and no car)
    this.renderer.render(this.scene, this.camera);
  }

  // ---- road -------------------------------------------------------------------------------------------
  build(info) {
    this.info = info;
    this.road = info.road;
    this.buildRoad(info.road);
    this.vehicle = this.buildVehicle(info, DEFAULT_COLOUR);
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
    return this.buildDrawing(info.shape, colour);
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
      const v = road.vertices, mu = road.mu, lo = Math.min(...mu), hi = Math.max(...mu);
      const asphalt = new THREE.Color('#5c5f63');
      this._muColours = mu.map((m) => frictionColour(m, lo - 0.05, hi + 0.05));
      const geo = triangleSoup(v, road.triangles, () => asphalt);
      geo.computeVertexNormals();
      geo.computeBoundingSphere();
      this.meshRoad = new THREE.Mesh(geo, new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }));
      this.scene.add(this.meshRoad);
      let zmin = Infinity;
      for (let i = 2; i < v.length; i += 3) zmin = Math.min(zmin, v[i]);
      this.groundZ = zmin - 0.3;                 // the plane under and around the survey
      ground.material.color.set('#8a9a7a');
      if (road.marks && road.marks.triangles.length) this.buildMarks(road.marks);
      const wallMat = new THREE.MeshLambertMaterial({ color: '#d9d4c7' });
      for (const b of road.buildings || []) {     // blocks from the file beside the survey
        const box = new THREE.Mesh(new THREE.BoxGeometry(b.length, b.width, b.height + 0.3), wallMat);
        box.position.set(b.x, b.y, b.z - 0.3 + (b.height + 0.3) / 2);
        box.rotation.z = b.yaw_deg * Math.PI / 180;
        this.scene.add(box);
      }
    }
  }

  // an OpenDRIVE road's marks: ribbons 1 cm above the lanes, a colour per triangle
  buildMarks(marks) {
    const geo = triangleSoup(marks.vertices, marks.triangles, (k) => new THREE.Color(marks.colour[k]));
    this.marks = new THREE.Mesh(geo, new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide }));
    this.scene.add(this.marks);
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

  // a vehicle from its drawing (rtsim.vehicle.kit.drawing, in its reference frame): the body's pieces, the
  // steering assembly turning about its axis through its head, the wheels on the body or the steering
  buildDrawing(s, colour) {
    const group = new THREE.Group();
    const paint = new THREE.MeshLambertMaterial({ color: colour === DEFAULT_COLOUR && s.paint ? s.paint : colour });
    const material = (c) => c === 'paint' ? paint : new THREE.MeshLambertMaterial({ color: c });
    let steering = null, axis = null, head = null;
    if (s.steering) {
      head = new THREE.Vector3(...s.steering.head);
      axis = new THREE.Vector3(...s.steering.axis).normalize();
      steering = new THREE.Group(); steering.position.copy(head); group.add(steering);
    }
    const carrierOf = (c) => (c === 'steering' && steering) ? steering : group;
    const local = (c, p) => { const v = new THREE.Vector3(...p); return carrierOf(c) === steering ? v.sub(head) : v; };
    for (const pc of s.pieces) {
      let mesh;
      if (pc.shape === 'sphere') {
        mesh = new THREE.Mesh(new THREE.SphereGeometry(pc.radius, 16, 12), material(pc.colour));
      } else if (pc.shape === 'cylinder') {
        mesh = new THREE.Mesh(new THREE.CylinderGeometry(pc.radius, pc.radius, pc.length, 8), material(pc.colour));
        mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(...pc.direction).normalize());
      } else mesh = new THREE.Mesh(new THREE.BoxGeometry(...pc.size), material(pc.colour));
      mesh.position.copy(local(pc.carrier, pc.at));
      if (pc.pitch) mesh.rotation.y = pc.pitch;
      if (pc.in_cockpit === false) mesh.userData.hideInCockpit = true;
      carrierOf(pc.carrier).add(mesh);
    }
    const wheels = [];
    for (const w of s.wheels) {
      const mount = new THREE.Group();          // at the design wheel centre; moves with the suspension
      const design = local(w.carrier, w.centre);
      mount.position.copy(design);
      const steer = new THREE.Group();
      const spin = this.wheelMesh(w.radius, w.width);
      steer.add(spin); mount.add(steer); carrierOf(w.carrier).add(mount);
      wheels.push({ spec: w, corner: w.name, design, mount, steer, spin, angle: 0,
                    onSteering: carrierOf(w.carrier) === steering });
    }
    const eye = new THREE.Object3D(); eye.position.set(...s.eye); group.add(eye);
    return { group, steering, axis, wheels, eye, shape: s };
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
    this.updateDrawing(v, st, sens || {}, dt, arrows);
    if (k !== 0) return;
    this.pose = this.poses[0];
    // the ground plane follows the vehicle (in whole tiles, so the grid stays put on the road)
    const gx = Math.round(st.pos_x / TILE) * TILE, gy = Math.round(st.pos_y / TILE) * TILE;
    this.ground.position.set(gx, gy, this.road.type === 'mesh' ? this.groundZ : this.roadHeight(gx, gy) - 0.002);
  }

  // a channel's value: the sensors' (as measured) where they have it, else the state's
  channel(st, sens, name) {
    if (!name) return NaN;
    const m = sens[name];
    return Number.isFinite(m) ? m : (Number.isFinite(st[name]) ? st[name] : NaN);
  }

  updateDrawing(v, st, sens, dt, arrows) {
    const s = v.shape;
    if (v.steering) {
      const d = st[s.steering.angle];
      v.steering.quaternion.setFromAxisAngle(v.axis, Number.isFinite(d) ? d : 0);
    }
    const inv = new THREE.Matrix4().copy(v.group.matrixWorld).invert();
    for (const w of v.wheels) {
      const spec = w.spec;
      if (spec.load) {
        // the wheel stands on the road: its centre at the road height + the loaded radius, in the body frame
        const p = w.design.clone().applyMatrix4(v.group.matrixWorld);
        const fz = st[spec.load];
        const r = spec.radius - Math.max(0, Number.isFinite(fz) ? fz : 0) / spec.stiffness;
        p.z = this.roadHeight(p.x, p.y) + r;
        const l = p.applyMatrix4(inv);
        w.mount.position.z = Math.min(w.design.z + s.wheel_travel, Math.max(w.design.z - s.wheel_travel, l.z));
      }
      if (w.onSteering) {
        // the fork's travel slides the wheel along the steering axis (towards the head)
        const t = st[s.steering.travel];
        w.mount.position.copy(w.design).addScaledVector(v.axis, Number.isFinite(t) ? t : 0);
      } else if (spec.steer) {
        const steer = this.channel(st, sens, spec.steer);
        w.steer.rotation.z = Number.isFinite(steer) ? steer : 0;
      }
      const ang = this.channel(st, sens, spec.spin);
      if (Number.isFinite(ang)) w.angle = ang;
      else w.angle += (st[spec.spin_rate] || 0) * dt;
      w.spin.rotation.y = w.angle;
    }
    if (arrows) this.updateArrows(v, st, v.wheels.map((w) => w.corner));
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
        const [back, up] = v.shape.chase;
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
