"""A ROS 2 IMU driver stand-in written with the PyPI `cyclonedds` package
(Eclipse Cyclone DDS, nothing of insuwb): publishes `sensor_msgs/Imu` under
its DDS type name `sensor_msgs::msg::dds_::Imu_` on `rt/<topic>` with the
sensor-data QoS of ROS IMU drivers (best effort, volatile, keep-last 5),
stamped with the real-time clock (ROS time) in frame `base_link`.

It waits (bounded) until a reader has matched, then publishes --count
samples at --rate Hz with known values; a few are deliberately invalid:
a NaN, an infinity, an out-of-range acceleration, and one stamped before
its predecessor. It writes what it published as JSON: each sample's stamp,
values and whether a receiver should keep it. Exit code 2 when no reader
matched.
"""

import argparse
import json
import math
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from ros_types import Header, Imu, Quaternion, Time, Vector3


# Sample index -> what is wrong with it.
INVALID = {40: "nan", 90: "inf", 140: "range", 190: "older"}


def values(k):
    """Known values of sample k: accelerometer (m/s^2) and gyro (rad/s)."""
    accel = [0.1 + 0.001 * k, -0.2 + 0.0005 * k, 9.81 - 0.0001 * k]
    gyro = [0.01 * math.sin(0.1 * k), -0.02, 0.3 + 0.001 * k]
    return accel, gyro


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--topic", required=True, help="ROS topic, e.g. /test_imu")
    ap.add_argument("--count", type=int, default=300)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--match-timeout", type=float, default=30.0)
    ap.add_argument("--settle", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    sensor_data = Qos(
        Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(5),
    )
    topic = Topic(dp, "rt/" + a.topic.strip("/"), Imu)
    writer = DataWriter(dp, topic, qos=sensor_data)

    # Bounded wait for the insuwb reader, then time for its side of the
    # discovery (best effort: a sample before that would be lost).
    deadline = time.monotonic() + a.match_timeout
    while not writer.get_matched_subscriptions():
        if time.monotonic() > deadline:
            print("imu publisher: no reader matched", file=sys.stderr, flush=True)
            return 2
        time.sleep(0.01)
    time.sleep(a.settle)

    published = []
    prev_stamp = None
    period = 1.0 / a.rate
    start = time.monotonic()
    for k in range(a.count):
        # Paced by the monotonic clock, bounded by count.
        delay = start + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        accel, gyro = values(k)
        what = INVALID.get(k)
        if what == "nan":
            accel[0] = float("nan")
        elif what == "inf":
            gyro[2] = float("inf")
        elif what == "range":
            accel[2] = 500.0
        stamp = time.time_ns()
        if what == "older":
            stamp = prev_stamp - 5_000_000
        msg = Imu(
            header=Header(
                stamp=Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000),
                frame_id="base_link",
            ),
            orientation=Quaternion(0.0, 0.0, 0.0, 1.0),
            orientation_covariance=[-1.0] + [0.0] * 8,
            angular_velocity=Vector3(*gyro),
            angular_velocity_covariance=[0.0] * 9,
            linear_acceleration=Vector3(*accel),
            linear_acceleration_covariance=[0.0] * 9,
        )
        writer.write(msg)
        published.append(
            {
                "stamp_ns": stamp,
                # JSON has no NaN or infinity: the invalid ones as strings.
                "accel": [v if math.isfinite(v) else str(v) for v in accel],
                "gyro": [v if math.isfinite(v) else str(v) for v in gyro],
                "invalid": what,
            }
        )
        if what != "older":
            prev_stamp = stamp
    # Let the last samples leave before the participant goes.
    time.sleep(0.5)
    with open(a.out, "w") as f:
        json.dump(published, f)
    print(
        f"imu publisher: {len(published)} samples on rt/{a.topic.strip('/')}, "
        f"{len(INVALID)} invalid",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
