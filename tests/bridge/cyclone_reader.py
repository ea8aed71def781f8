#!/usr/bin/env python3
"""Reads ROS 2 topics of `dvrk-sidecar ros2-bridge` with Cyclone DDS (an independent DDS
implementation, the one under ROS 2's rmw_cyclonedds) and prints one JSON object per sample.

The IDL types (ros2_types.py, beside this file) are declared from the ROS 2 message definitions,
with the DDS type names the ROS 2 rmw layers register (`geometry_msgs::msg::dds_::PoseStamped_`),
so a match proves that a ROS 2 node would receive them.

Types: pose (geometry_msgs/PoseStamped), pose-cov (geometry_msgs/PoseWithCovarianceStamped: the
pose, then "covariance", its 36 doubles row-major), joints (sensor_msgs/JointState).

Usage: cyclone_reader.py --domain N --topic rt/PSM1/compensated/local/measured_cp [--topic ...]
                         --type pose|pose-cov|joints --count K --timeout-s T
                         [--reliability reliable|best-effort] [--durability volatile|transient-local]
                         [--depth D]
The QoS is by default ROS 2's default subscriber profile: RELIABLE, KEEP_LAST 10, VOLATILE.
Each line carries the topic; every topic (all of one type) must bring K samples.
Exit status 0 when K samples were read on every topic, 2 on timeout.
"""

import argparse
import json
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_types import JointState, PoseStamped, PoseWithCovarianceStamped


def to_json(kind, s):
    h = {"sec": s.header.stamp.sec, "nanosec": s.header.stamp.nanosec,
         "frame_id": s.header.frame_id}
    if kind == "pose":
        p, q = s.pose.position, s.pose.orientation
        return {"header": h, "position": [p.x, p.y, p.z],
                "orientation_xyzw": [q.x, q.y, q.z, q.w]}
    if kind == "pose-cov":
        p, q = s.pose.pose.position, s.pose.pose.orientation
        return {"header": h, "position": [p.x, p.y, p.z],
                "orientation_xyzw": [q.x, q.y, q.z, q.w],
                "covariance": list(s.pose.covariance)}
    return {"header": h, "name": list(s.name), "position": list(s.position),
            "velocity": list(s.velocity), "effort": list(s.effort)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--topic", action="append", required=True)
    ap.add_argument("--type", choices=["pose", "pose-cov", "joints"], required=True)
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--timeout-s", type=float, default=30.0)
    ap.add_argument("--reliability", choices=["reliable", "best-effort"], default="reliable")
    ap.add_argument("--durability", choices=["volatile", "transient-local"], default="volatile")
    ap.add_argument("--depth", type=int, default=10,
                    help="KEEP_LAST depth (ROS 2's default 10; deeper so that a starved reader "
                         "loses nothing of a burst)")
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    ty = {"pose": PoseStamped, "pose-cov": PoseWithCovarianceStamped,
          "joints": JointState}[a.type]
    rel = (Policy.Reliability.Reliable(duration(milliseconds=100)) if a.reliability == "reliable"
           else Policy.Reliability.BestEffort)
    dur = (Policy.Durability.TransientLocal if a.durability == "transient-local"
           else Policy.Durability.Volatile)
    qos = Qos(rel, dur, Policy.History.KeepLast(a.depth))
    readers = [(name, DataReader(dp, Topic(dp, name, ty), qos=qos)) for name in a.topic]
    print(json.dumps({"ready": True}), flush=True)
    got = {name: 0 for name in a.topic}
    end = time.monotonic() + a.timeout_s
    while min(got.values()) < a.count and time.monotonic() < end:
        for name, reader in readers:
            for s in reader.take(N=1000):
                if got[name] < a.count:
                    out = to_json(a.type, s)
                    out["topic"] = name
                    print(json.dumps(out), flush=True)
                    got[name] += 1
        if min(got.values()) < a.count:
            time.sleep(0.002)
    if min(got.values()) < a.count:
        print(f"timeout: {got} of {a.count} samples each", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
