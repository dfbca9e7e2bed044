"""A fleet subscriber with no insuwb code: the PyPI `eclipse-zenoh` package
for the transport, `rosbags` for the CDR of nav_msgs/msg/Odometry, `json`
for the rest (docs/ZENOH.md).

It runs its own Zenoh peer listening on --listen (the robot's bridge
connects to it; no scouting), subscribes to insuwb/<robot>/pose and
insuwb/<robot>/health, and records for --duration seconds after the first
pose: every pose (stamp, position, orientation, covariance diagonal,
frames, encoding, attachment), every health sample as received, and the
receive times. Writes one JSON object to --out. Exits non-zero when no
pose or no health sample came within --first-timeout seconds.
"""

import argparse
import json
import sys
import threading
import time

import zenoh
from rosbags.typesys import Stores, get_typestore


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--listen", required=True, help="e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--robot", required=True)
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--first-timeout", type=float, default=30.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    typestore = get_typestore(Stores.ROS2_JAZZY)
    lock = threading.Lock()
    poses, health, errors = [], [], []
    first = threading.Event()

    def on_pose(sample):
        rx = time.monotonic()
        try:
            att = json.loads(bytes(sample.attachment.to_bytes()))
            odom = typestore.deserialize_cdr(
                bytes(sample.payload.to_bytes()), "nav_msgs/msg/Odometry"
            )
            p = odom.pose.pose
            cov = odom.pose.covariance
            rec = {
                "rx_s": rx,
                "key": str(sample.key_expr),
                "encoding": str(sample.encoding),
                "attachment": att,
                "stamp_ns": odom.header.stamp.sec * 1_000_000_000
                + odom.header.stamp.nanosec,
                "frame_id": odom.header.frame_id,
                "child_frame_id": odom.child_frame_id,
                "position": [p.position.x, p.position.y, p.position.z],
                "orientation": [
                    p.orientation.x,
                    p.orientation.y,
                    p.orientation.z,
                    p.orientation.w,
                ],
                "pos_var": [float(cov[0]), float(cov[7]), float(cov[14])],
            }
        except Exception as e:  # noqa: BLE001 - recorded, the test fails on it
            with lock:
                errors.append(f"pose: {e!r}")
            return
        with lock:
            poses.append(rec)
        first.set()

    def on_health(sample):
        rx = time.monotonic()
        try:
            rec = {
                "rx_s": rx,
                "key": str(sample.key_expr),
                "encoding": str(sample.encoding),
                "attachment": json.loads(bytes(sample.attachment.to_bytes())),
                "body": json.loads(bytes(sample.payload.to_bytes())),
            }
        except Exception as e:  # noqa: BLE001
            with lock:
                errors.append(f"health: {e!r}")
            return
        with lock:
            health.append(rec)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([a.listen]))
    conf.insert_json5("connect/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    with zenoh.open(conf) as session:
        subs = [
            session.declare_subscriber(f"insuwb/{a.robot}/pose", on_pose),
            session.declare_subscriber(f"insuwb/{a.robot}/health", on_health),
        ]
        print(f"subscriber: listening on {a.listen}", file=sys.stderr, flush=True)
        if not first.wait(a.first_timeout):
            print("subscriber: no pose came", file=sys.stderr)
            sys.exit(2)
        time.sleep(a.duration)
        for s in subs:
            s.undeclare()
    with lock:
        out = {"poses": poses, "health": health, "errors": errors}
    with open(a.out, "w", encoding="utf-8") as f:
        json.dump(out, f)
    print(
        f"subscriber: {len(poses)} poses, {len(health)} health samples, "
        f"{len(errors)} errors",
        file=sys.stderr,
    )
    if not health:
        sys.exit(3)


if __name__ == "__main__":
    main()
