#!/usr/bin/env python3
"""A dVRK console's CRTK interface for one PSM, written with Cyclone DDS (the DDS under ROS 2's
rmw_cyclonedds) and an arm model of its own: an independent stand-in for `dvrk_system`, to
check that `dvrk-sidecar` works with a console that is not the project's own `sim --crtk`.

The DDS type names are those the ROS 2 rmw layers register (`sensor_msgs::msg::dds_::JointState_`,
`crtk_msgs::msg::dds_::OperatingState_`), the topics the console's (`rt/PSM1/measured_js`, ...),
the QoS cisst-ros's: periodic state RELIABLE, KEEP_LAST 100, VOLATILE; events RELIABLE,
KEEP_LAST 100, TRANSIENT_LOCAL; command readers RELIABLE.

The arm: yaw, pitch and insertion, each a mass under a PD controller of its own gain (`--kp`,
critically damped), with a weight torque of its own (`tau_g = g sin(q)`), measured effort =
the controller's output + noise. `move_jp` follows a cosine profile at `trajectory_j/set_ratio`
of the PSM's speed (busy true, then busy false and `goal_reached` true); `servo_jp` sets the
setpoint; `hold` stops where the arm is; `state_command` `enable` and `home` bring it to
ENABLED and homed (after `--home-s`). `measured_js` at `--rate` Hz (6 joints), `measured_cp`
and `local/measured_cp` at the same rate, each message stamped as it is written (microseconds
apart, unlike the dVRK console's), `tool_type` once (TRANSIENT_LOCAL).

Standard input takes lines while it runs (the operator's and the console's own doings): `tool
NAME` publishes a tool_type (`tool` alone: removed), `state S` an operating state (e.g. FAULT),
`home` and `unhome` set and clear homing, `base X Y Z` moves the base frame (m).

Standard output: one JSON object per line, for each command received
({"t": s, "cmd": "servo_jp", "position": [...]}) and each event sent ({"t": s, "event": ...}).

`--ki` (N m/(rad s)) adds an integral term and drops the weight's feed-forward: the integral
carries the weight, so after each step the effort creeps to its final value.

`--fixture clamp` plays the lab's clamp-beam experiment: the operator clamps the shaft's far end
where it is once the arm has been still for 0.5 s after an insertion move (and at start), and
releases it before a command moves the insertion. The clamped shaft is this stand-in's own: a
play of `BACKLASH` and a stiffness linear in the insertion (`STIFFNESS`), logged with each
clamp. `--friction-nm` adds Coulomb friction to the yaw and pitch motors (they stick while the
rest of the torque stays within it). `--fixture divot` holds the tip in a divot: the same shaft
held where the arm first comes to rest, never released.

`--events-volatile` gives the event writers VOLATILE durability (unlike the dVRK console's);
`--silent-start` publishes no event at start (a reader of VOLATILE events that joined late
knows nothing until the next change). `--ratio-topic` publishes `trajectory_j/ratio` as the
dVRK 2.x console does (an event: the ratio at start, 0.2, and each `set_ratio` taken);
`--ignore-ratio` takes no `set_ratio` (logged, neither applied nor echoed).

Usage: cyclone_console.py --domain N [--arm PSM1] [--rate 100] [--kp 40] [--start disabled|enabled|homed]
                          [--tool NAME] [--home-s 1.0] [--noise-nm 0.002] [--seconds 600]
                          [--events-volatile] [--silent-start] [--fixture none|clamp|divot]
                          [--friction-nm 0] [--ki 0] [--ratio-topic] [--ignore-ratio]
"""

import argparse
import json
import math
import os
import random
import select
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader, InvalidSample
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_types import (Bool, Empty, Float64, Header, JointState, OperatingState, Point, Pose,
                        PoseStamped, Quaternion, String, StringStamped, Time)


NAMES = ["outer_yaw", "outer_pitch", "outer_insertion", "outer_roll", "outer_wrist_pitch",
         "outer_wrist_yaw"]
# the PSM's speed and acceleration for move_jp at ratio 1 (rad/s, rad/s, m/s)
VMAX = [math.pi / 2, math.pi / 2, 0.2]
LIMITS = [(-1.5, 1.5), (-0.9, 0.9), (0.0, 0.24)]
# masses (kg m², kg m², kg) and weight torques (N m, N m, N)
INERTIA = [0.05, 0.05, 0.2]
WEIGHT = [0.08, -0.12, 0.3]
# the shaft of `--fixture clamp` and `divot`: half-width of its play (rad) and stiffness
# (N m/rad) at the insertion L (m), linear in L (the simulator's is a cubic of other values)
BACKLASH = [0.0025, 0.002]
STIFFNESS = [(11.0, 60.0), (20.0, 80.0)]


def stiffness(j, l):
    return STIFFNESS[j][0] + STIFFNESS[j][1] * l


class Arm:
    def __init__(self, kp, ki, noise, friction):
        self.q = [0.0, 0.0, 0.12]
        self.v = [0.0, 0.0, 0.0]
        self.sp = list(self.q)
        self.kp = kp
        self.ki = ki
        self.integral = [0.0, 0.0, 0.0]
        self.noise = noise
        self.friction = friction
        self.effort = [0.0, 0.0, 0.0]
        # the clamp: the shaft's far end held at these yaw and pitch angles (None: free)
        self.anchor = None

    def shaft_load(self, j):
        """The torque the clamped shaft puts on the motor side of joint j (0 unclamped): none
        inside the play, the spring's beyond it."""
        if self.anchor is None or j > 1:
            return 0.0
        x = self.q[j] - self.anchor[j]
        beyond = abs(x) - BACKLASH[j]
        return -math.copysign(stiffness(j, self.q[2]) * beyond, x) if beyond > 0.0 else 0.0

    def step(self, dt):
        for j in range(3):
            # kp in N m/rad for the rotary joints, scaled by the mass for insertion
            kp = self.kp * INERTIA[j] / INERTIA[0]
            kd = 2.0 * math.sqrt(kp * INERTIA[j])
            if self.anchor is not None and j < 2:
                # damped for the clamped shaft's spring as well
                kd = 2.0 * math.sqrt((kp + stiffness(j, self.q[2])) * INERTIA[j])
            g = WEIGHT[j] * (math.sin(self.q[j]) if j < 2 else 1.0)
            e = self.sp[j] - self.q[j]
            if self.ki > 0.0:
                # PID without the weight's feed-forward: the integral carries the weight (and
                # creeps to it after each step), bounded against wind-up
                ki = self.ki * INERTIA[j] / INERTIA[0]
                self.integral[j] = max(-2.0, min(2.0, self.integral[j] + ki * e * dt))
                u = kp * e - kd * self.v[j] + self.integral[j]
            else:
                u = kp * e - kd * self.v[j] + g
            net = u - g + self.shaft_load(j)
            # Coulomb friction, sticking while the rest of the torque stays within it
            if self.friction > 0.0 and j < 2:
                if abs(self.v[j]) < 1e-4 and abs(net) <= self.friction:
                    self.v[j] = 0.0
                    self.effort[j] = u
                    continue
                net -= math.copysign(self.friction, self.v[j] if self.v[j] != 0.0 else net)
            a = net / INERTIA[j]
            self.v[j] += a * dt
            self.q[j] += self.v[j] * dt
            self.effort[j] = u

    def measured_effort(self):
        return [e + random.gauss(0.0, self.noise) for e in self.effort] + [0.0, 0.0, 0.0]


def stamp():
    t = time.time()
    return Header(Time(int(t), int((t - int(t)) * 1e9)), "")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--arm", default="PSM1")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--kp", type=float, default=40.0)
    ap.add_argument("--start", choices=["disabled", "enabled", "homed"], default="homed")
    ap.add_argument("--tool", default="LARGE_NEEDLE_DRIVER:400006")
    ap.add_argument("--home-s", type=float, default=1.0)
    ap.add_argument("--noise-nm", type=float, default=0.002)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--events-volatile", action="store_true")
    ap.add_argument("--silent-start", action="store_true")
    ap.add_argument("--fixture", choices=["none", "clamp", "divot"], default="none")
    ap.add_argument("--friction-nm", type=float, default=0.0)
    ap.add_argument("--ki", type=float, default=0.0)
    ap.add_argument("--ratio-topic", action="store_true")
    ap.add_argument("--ignore-ratio", action="store_true")
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    rel = Policy.Reliability.Reliable(duration(seconds=1))
    state_qos = Qos(rel, Policy.History.KeepLast(100), Policy.Durability.Volatile)
    event_qos = Qos(rel, Policy.History.KeepLast(100),
                    Policy.Durability.Volatile if a.events_volatile else Policy.Durability.TransientLocal)
    cmd_qos = Qos(rel, Policy.History.KeepLast(10), Policy.Durability.Volatile)

    def writer(name, ty, qos):
        return DataWriter(dp, Topic(dp, f"rt/{a.arm}/{name}", ty), qos)

    def reader(name, ty):
        return DataReader(dp, Topic(dp, f"rt/{a.arm}/{name}", ty), cmd_qos)

    js_w = writer("measured_js", JointState, state_qos)
    cp_w = writer("measured_cp", PoseStamped, state_qos)
    lcp_w = writer("local/measured_cp", PoseStamped, state_qos)
    os_w = writer("operating_state", OperatingState, event_qos)
    goal_w = writer("goal_reached", Bool, event_qos)
    tool_w = writer("tool_type", String, event_qos)
    warn_w = writer("warning", String, event_qos)
    err_w = writer("error", String, event_qos)
    ratio_w = writer("trajectory_j/ratio", Float64, event_qos) if a.ratio_topic else None
    readers = {
        "move_jp": reader("move_jp", JointState),
        "servo_jp": reader("servo_jp", JointState),
        "hold": reader("hold", Empty),
        "state_command": reader("state_command", StringStamped),
        "set_ratio": reader("trajectory_j/set_ratio", Float64),
    }

    t0 = time.monotonic()

    def log(obj):
        obj["t"] = round(time.monotonic() - t0, 4)
        print(json.dumps(obj), flush=True)

    state = {"disabled": "DISABLED"}.get(a.start, "ENABLED")
    homed = a.start == "homed"
    busy = False

    def publish_state():
        os_w.write(OperatingState(stamp(), state, homed, busy))
        log({"event": "operating_state", "state": state, "homed": homed, "busy": busy})

    if not a.silent_start:
        publish_state()
        tool_w.write(String(a.tool))
        log({"event": "tool_type", "tool": a.tool})

    arm = Arm(a.kp, a.ki, a.noise_nm, a.friction_nm)
    # the operator of `--fixture clamp` (and `divot`): clamps once the arm has been still for
    # 0.5 s after an insertion move (and at start), releases before the insertion moves again
    # (the divot: never)
    clamp_wanted = a.fixture != "none"
    still_since = None
    ratio = 0.2
    if ratio_w is not None:
        ratio_w.write(Float64(ratio))
        log({"event": "ratio", "ratio": ratio})
    move = None  # (start setpoint, target, start time, duration)
    homing_until = None
    base = [0.1, 0.2, 0.05]
    period = 1.0 / a.rate
    substeps = max(1, int(round(period / 0.0005)))
    next_t = time.monotonic()
    pending, stdin_open = "", True
    while time.monotonic() - t0 < a.seconds:
        # operator lines (read from the descriptor: a buffered readline would keep a second
        # line that arrived with the first out of select's sight)
        if stdin_open and select.select([0], [], [], 0)[0]:
            chunk = os.read(0, 4096)
            stdin_open = bool(chunk)
            pending += chunk.decode()
        while "\n" in pending:
            line, pending = pending.split("\n", 1)
            words = line.split()
            if not words:
                continue
            if words[0] == "tool":
                tool_w.write(String(words[1] if len(words) > 1 else ""))
                log({"event": "tool_type", "tool": words[1] if len(words) > 1 else ""})
            elif words[0] == "state":
                state = words[1]
                move = None
                busy = False
                publish_state()
            elif words[0] == "unhome":
                homed = False
                publish_state()
            elif words[0] == "home":
                homed = True
                publish_state()
            elif words[0] == "base":
                base = [float(x) for x in words[1:4]]
                log({"event": "base", "base": base})

        # commands
        for name, r in readers.items():
            for s in r.take(N=100):
                if isinstance(s, InvalidSample):
                    continue  # a writer went away (its disposal), no command
                if name == "set_ratio":
                    log({"cmd": name, "ratio": s.data})
                    if 0.0 < s.data <= 1.0 and not a.ignore_ratio:
                        ratio = s.data
                        if ratio_w is not None:
                            ratio_w.write(Float64(ratio))
                            log({"event": "ratio", "ratio": ratio})
                    continue
                if name == "state_command":
                    log({"cmd": name, "command": s.data})
                    if s.data == "enable" and state != "FAULT":
                        state = "ENABLED"
                        publish_state()
                    elif s.data == "disable":
                        state = "DISABLED"
                        move = None
                        busy = False
                        publish_state()
                    elif s.data == "home" and state == "ENABLED":
                        busy = True
                        publish_state()
                        homing_until = time.monotonic() + a.home_s
                    continue
                if name == "hold":
                    log({"cmd": name})
                    if state == "ENABLED":
                        if move is not None:
                            goal_w.write(Bool(False))
                            busy = False
                            publish_state()
                        move = None
                        arm.sp = list(arm.q)
                    continue
                pos = list(s.position[:3])
                log({"cmd": name, "position": pos})
                if state != "ENABLED" or not homed or len(pos) < 3:
                    warn_w.write(String(f"{a.arm}: {name} refused, arm not ready"))
                    log({"event": "warning", "refused": name})
                    continue
                if any(not (lo <= p <= hi) for p, (lo, hi) in zip(pos, LIMITS)):
                    err_w.write(String(f"{a.arm}: {name} outside the joint limits"))
                    log({"event": "error", "refused": name})
                    state = "FAULT"
                    move = None
                    busy = False
                    publish_state()
                    continue
                moves_insertion = abs(pos[2] - arm.sp[2]) > 1e-3
                if a.fixture == "clamp" and arm.anchor is not None and moves_insertion:
                    arm.anchor = None
                    clamp_wanted = True
                    log({"event": "operator", "fixture": "released"})
                if name == "servo_jp":
                    move = None
                    arm.sp = pos
                else:
                    d = max(abs(p - s0) / (v * ratio) for p, s0, v in zip(pos, arm.sp, VMAX))
                    move = (list(arm.sp), pos, time.monotonic(), max(d * 1.5, 0.05))
                    busy = True
                    publish_state()

        now = time.monotonic()
        if homing_until is not None and now >= homing_until:
            homing_until = None
            homed = True
            busy = False
            publish_state()
        if move is not None:
            s0, target, start, dur = move
            f = min(1.0, (now - start) / dur)
            c = 0.5 - 0.5 * math.cos(math.pi * f)
            arm.sp = [x + c * (y - x) for x, y in zip(s0, target)]
            if f >= 1.0:
                move = None
                busy = False
                goal_w.write(Bool(True))
                log({"event": "goal_reached", "value": True})
                publish_state()
        if clamp_wanted and move is None and homing_until is None:
            if max(abs(v) for v in arm.v) > 1e-3:
                still_since = None
            elif still_since is None:
                still_since = now
            elif now - still_since >= 0.5:
                arm.anchor = arm.q[:2]
                clamp_wanted = False
                still_since = None
                done = "clamped" if a.fixture == "clamp" else "in divot"
                log({"event": "operator", "fixture": done, "insertion": arm.q[2],
                     "anchor": arm.anchor,
                     "stiffness_nm_per_rad": [stiffness(j, arm.q[2]) for j in range(2)],
                     "backlash_rad": BACKLASH})
        if state == "ENABLED":
            for _ in range(substeps):
                arm.step(period / substeps)

        # each message stamped as it is written (the dVRK console gives all three the time of
        # their joint reading; a console of another kind may not)
        js_w.write(JointState(stamp(), NAMES, list(arm.q) + [0.0, 0.0, 0.0],
                              list(arm.v) + [0.0, 0.0, 0.0], arm.measured_effort()))
        # the tip in the RCM frame (a point on the shaft at the insertion) and in the base frame
        y, p, l = arm.q
        tip = [l * math.sin(y) * math.cos(p), -l * math.sin(p), -l * math.cos(y) * math.cos(p)]
        q_id = Quaternion(0.0, 0.0, 0.0, 1.0)
        lcp_w.write(PoseStamped(stamp(), Pose(Point(*tip), q_id)))
        cp_w.write(PoseStamped(stamp(), Pose(Point(*[t + b for t, b in zip(tip, base)]), q_id)))

        next_t += period
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.monotonic()


if __name__ == "__main__":
    main()
