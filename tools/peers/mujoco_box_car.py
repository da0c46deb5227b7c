#!/usr/bin/env python3
"""MuJoCo's 14-DOF box car on a plane at 1 ms: the peer `rtsim bench --suite vehicle` is compared with.

The car: a free-floating box chassis (6 DOF), four slide joints along the chassis' z axis as the
suspensions (spring and damper on each joint), four hinge joints for the wheels (cylinders); the
wheels touch the plane through MuJoCo's contact with friction (no tyre model), implicitfast integrator,
1 ms step. It rolls on from 22.22 m/s (80 km/h) with a small drive torque on the rear wheels.

Prints microseconds per step: the median of 3 blocks of steps run in MuJoCo's compiled rollout loop
(mujoco.rollout, one thread: no Python per step, like rtsim's compiled stepping loop), and beside it the
same with one Python call of mujoco.mj_step per step.

MuJoCo is an optional dependency: pip install 'rtsim[peers]' (or pip install mujoco)."""
from __future__ import annotations

import argparse
import statistics
import sys
import time

MASS = 1500.0           # kg, chassis
WHEEL_MASS = 20.0       # kg, each wheel (upright and wheel together)
RADIUS = 0.3            # m
SPEED = 22.22           # m/s
TRACK, BASE = 1.6, 2.7  # m
K_SUSP, C_SUSP = 35000.0, 3500.0   # N/m, N s/m per corner

XML = f"""
<mujoco model="box_car">
  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" friction="1.0 0.005 0.0001"/>
    <body name="chassis" pos="0 0 0.65">
      <freejoint/>
      <geom type="box" size="2.2 0.85 0.3" mass="{MASS}" contype="0" conaffinity="0"/>
      {"".join(f'''
      <body name="corner{i}" pos="{x} {y} -0.3">
        <joint name="susp{i}" type="slide" axis="0 0 1" stiffness="{K_SUSP}" damping="{C_SUSP}"
               springref="0.1" range="-0.15 0.15" limited="true"/>
        <geom type="sphere" size="0.05" mass="{WHEEL_MASS / 2}" contype="0" conaffinity="0"/>
        <body name="wheel{i}">
          <joint name="spin{i}" type="hinge" axis="0 1 0"/>
          <geom type="cylinder" size="{RADIUS} 0.1" euler="90 0 0" mass="{WHEEL_MASS / 2}"
                friction="1.0 0.005 0.0001" condim="3"/>
        </body>
      </body>''' for i, (x, y) in enumerate(((BASE / 2, TRACK / 2), (BASE / 2, -TRACK / 2),
                                                (-BASE / 2, TRACK / 2), (-BASE / 2, -TRACK / 2))))}
    </body>
  </worldbody>
  <actuator>
    <motor joint="spin2" gear="1"/>
    <motor joint="spin3" gear="1"/>
  </actuator>
</mujoco>
"""


def build():
    import mujoco
    import numpy as np

    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    assert model.nv == 14, model.nv
    data.qvel[0] = SPEED
    for i in range(4):
        data.qvel[model.jnt_dofadr[model.joint(f"spin{i}").id]] = SPEED / RADIUS
    data.ctrl[:] = 20.0                     # N m on each rear wheel
    mujoco.mj_forward(model, data)
    for _ in range(500):                    # settle onto the suspension
        mujoco.mj_step(model, data)
    return mujoco, np, model, data


def rollout_us(mujoco, np, model, data, steps: int) -> float:
    """us per step of `steps` steps in MuJoCo's compiled rollout loop (one thread)."""
    from mujoco import rollout

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state0, spec)
    ctrl = np.tile(data.ctrl, (1, steps, 1))
    out = np.empty((1, steps, state0.size))
    t0 = time.perf_counter()
    rollout.rollout(model, data, state0[None, :], ctrl, state=out)
    us = (time.perf_counter() - t0) / steps * 1e6
    mujoco.mj_setState(model, data, out[0, -1], spec)
    return us


def python_loop_us(mujoco, model, data, steps: int) -> float:
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return (time.perf_counter() - t0) / steps * 1e6


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=3000, help="steps per block (3000)")
    args = p.parse_args(argv)
    if args.steps < 1:
        print(f"mujoco_box_car: --steps must be at least 1, got {args.steps}", file=sys.stderr)
        return 2
    try:
        import mujoco  # noqa: F401
    except ImportError:
        print("mujoco_box_car: MuJoCo is not installed; install it with: pip install 'rtsim[peers]' "
              "(or pip install mujoco)")
        return 1
    mujoco, np, model, data = build()
    rollout_us(mujoco, np, model, data, 200)                 # load the rollout module, warm
    blocks = [rollout_us(mujoco, np, model, data, args.steps) for _ in range(3)]
    loop = [python_loop_us(mujoco, model, data, args.steps) for _ in range(3)]
    if not all(np.isfinite(data.qpos)) or data.qpos[2] < 0.2:
        print("mujoco_box_car: the car left its wheels during the benchmark", file=sys.stderr)
        return 1
    print(f"MuJoCo {mujoco.__version__} box car (nv = {model.nv}, implicitfast, 1 ms, contact friction): "
          f"{statistics.median(blocks):.1f} us/step (median of 3 blocks of {args.steps}, compiled rollout "
          f"loop); {statistics.median(loop):.1f} us/step with a Python call per step; speed "
          f"{float(np.hypot(data.qvel[0], data.qvel[1])):.1f} m/s at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
