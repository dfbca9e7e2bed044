"""A ROS 2 subscriber written with the PyPI `cyclonedds` package (Eclipse
Cyclone DDS, nothing of insuwb): the ROS 2 types under their DDS names, on
the DDS topics a ROS 2 node uses (`rt/...`). It receives the bridge's
odometry, TF, static TF (as a late joiner), IMU and diagnostics for
--duration seconds after the first odometry, and writes what it got as JSON.

Every loop is bounded by a deadline; exit code 2 when no odometry came.
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

from ros_types import DiagnosticArray, Imu, Odometry, TFMessage


def ns(t):
    return t.sec * 1_000_000_000 + t.nanosec


def tf_json(t):
    return {
        "stamp_ns": ns(t.header.stamp),
        "frame_id": t.header.frame_id,
        "child_frame_id": t.child_frame_id,
        "translation": [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
        "rotation": [t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w],
    }


def odom_json(m, rx):
    p, q = m.pose.pose.position, m.pose.pose.orientation
    v = m.twist.twist.linear
    return {
        "stamp_ns": ns(m.header.stamp),
        "rx_ns": rx,
        "frame_id": m.header.frame_id,
        "child_frame_id": m.child_frame_id,
        "position": [p.x, p.y, p.z],
        "orientation": [q.x, q.y, q.z, q.w],
        "pose_covariance": list(m.pose.covariance),
        "linear": [v.x, v.y, v.z],
        "twist_covariance": list(m.twist.covariance),
    }


def imu_json(m):
    return {
        "stamp_ns": ns(m.header.stamp),
        "frame_id": m.header.frame_id,
        "orientation_covariance": list(m.orientation_covariance),
        "angular_velocity": [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z],
        "linear_acceleration": [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z],
    }


def diag_json(m):
    return {
        "stamp_ns": ns(m.header.stamp),
        "status": [
            {
                "level": int(s.level),
                "name": s.name,
                "message": s.message,
                "hardware_id": s.hardware_id,
                "values": {kv.key: kv.value for kv in s.values},
            }
            for s in m.status
        ],
    }


def take(reader):
    # Valid samples only (take also hands over disposals as InvalidSample).
    return [s for s in reader.take(N=512) if not type(s).__name__.startswith("Invalid")]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--namespace", default="/insuwb")
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--first-timeout", type=float, default=30.0)
    ap.add_argument("--late-join-after", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    reliable = Policy.Reliability.Reliable(duration(seconds=1))
    volatile = Qos(reliable, Policy.Durability.Volatile, Policy.History.KeepLast(100))
    latched = Qos(reliable, Policy.Durability.TransientLocal, Policy.History.KeepLast(10))
    ns_ = a.namespace.strip("/")
    readers = {
        "odom": DataReader(dp, Topic(dp, f"rt/{ns_}/odom", Odometry), qos=volatile),
        "tf": DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=volatile),
        "imu": DataReader(dp, Topic(dp, f"rt/{ns_}/imu", Imu), qos=volatile),
        "diagnostics": DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=volatile),
    }
    got = {"odom": [], "tf": [], "imu": [], "diagnostics": [], "tf_static": []}
    start = time.monotonic()
    first = None
    tf_static = None
    # Bounded: at most first_timeout + duration seconds, 2 ms per round.
    while True:
        now = time.monotonic()
        if first is None and now - start > a.first_timeout:
            break
        if first is not None and now - first > a.duration:
            break
        rx = time.monotonic_ns()
        for m in take(readers["odom"]):
            got["odom"].append(odom_json(m, rx))
        for m in take(readers["tf"]):
            got["tf"].append([tf_json(t) for t in m.transforms])
        for m in take(readers["imu"]):
            got["imu"].append(imu_json(m))
        for m in take(readers["diagnostics"]):
            got["diagnostics"].append(diag_json(m))
        if first is None and got["odom"]:
            first = now
        # The late joiner: /tf_static read by a reader created well after
        # the bridge published it, so only transient-local durability delivers it.
        if tf_static is None and first is not None and now - first > a.late_join_after:
            tf_static = DataReader(dp, Topic(dp, "rt/tf_static", TFMessage), qos=latched)
        if tf_static is not None:
            for m in take(tf_static):
                got["tf_static"].append([tf_json(t) for t in m.transforms])
        time.sleep(0.002)
    with open(a.out, "w") as f:
        json.dump(got, f)
    counts = {k: len(v) for k, v in got.items()}
    print(f"cyclonedds subscriber: {counts}", flush=True)
    return 0 if got["odom"] else 2


if __name__ == "__main__":
    sys.exit(main())
