"""A ROS 2 wheel-odometry driver stand-in written with the PyPI `cyclonedds`
package (Eclipse Cyclone DDS, nothing of insuwb): publishes `nav_msgs/Odometry`
under its DDS type name `nav_msgs::msg::dds_::Odometry_` on `rt/<topic>`
(reliable, volatile, keep-last 10, as base drivers publish), stamped with the
real-time clock (ROS time), pose in `odom`, twist in `base_link`.

It waits (bounded) until a reader has matched, then publishes --count
messages at --rate Hz with known twists and twist covariances (per axis: a
variance, 0 for "unset", or 1e6 for "unknown"); a few are deliberately
invalid: a NaN velocity, a negative variance, and one stamped before its
predecessor. It writes what it published as JSON: each message's stamp,
linear velocity, variances of the three linear axes and whether a receiver
should keep it. Exit code 2 when no reader matched.
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
from cyclonedds.util import duration

from ros_types import (
    Header,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Time,
    Twist,
    TwistWithCovariance,
    Vector3,
)


# Message index -> what is wrong with it.
INVALID = {30: "nan", 70: "negative", 110: "older"}


def values(k):
    """Known twist of message k: linear velocity (m/s) and the variances of
    its three axes (m^2/s^2): x set, y unset (0) every other message, z
    unknown (1e6) but for every fifth message."""
    vel = [0.5 + 0.01 * k, 0.02 * math.sin(0.2 * k), -0.001 * k]
    var = [
        0.0004 * (1 + k % 3),
        0.0 if k % 2 == 0 else 0.0025,
        0.0001 if k % 5 == 0 else 1e6,
    ]
    return vel, var


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--topic", required=True, help="ROS topic, e.g. /wheel/odom")
    ap.add_argument("--count", type=int, default=150)
    ap.add_argument("--rate", type=float, default=50.0)
    ap.add_argument("--match-timeout", type=float, default=30.0)
    ap.add_argument("--settle", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
    )
    topic = Topic(dp, "rt/" + a.topic.strip("/"), Odometry)
    writer = DataWriter(dp, topic, qos=qos)

    # Bounded wait for the insuwb reader, then time for its side of the
    # discovery (its reader is best effort: a message before that is lost).
    deadline = time.monotonic() + a.match_timeout
    while not writer.get_matched_subscriptions():
        if time.monotonic() > deadline:
            print("odometry publisher: no reader matched", file=sys.stderr, flush=True)
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
        vel, var = values(k)
        what = INVALID.get(k)
        if what == "nan":
            vel[0] = float("nan")
        elif what == "negative":
            var[1] = -0.0025
        stamp = time.time_ns()
        if what == "older":
            stamp = prev_stamp - 5_000_000
        cov = [0.0] * 36
        for i in range(3):
            cov[i * 7] = var[i]
        # Angular rows: unknown, as base drivers often send them.
        for i in range(3, 6):
            cov[i * 7] = 1e6
        msg = Odometry(
            header=Header(
                stamp=Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000),
                frame_id="odom",
            ),
            child_frame_id="base_link",
            pose=PoseWithCovariance(
                pose=Pose(
                    position=Point(0.02 * k, 0.0, 0.0),
                    orientation=Quaternion(0.0, 0.0, 0.0, 1.0),
                ),
                covariance=[0.0] * 36,
            ),
            twist=TwistWithCovariance(
                twist=Twist(linear=Vector3(*vel), angular=Vector3(0.0, 0.0, 0.1)),
                covariance=cov,
            ),
        )
        writer.write(msg)
        published.append(
            {
                "stamp_ns": stamp,
                # JSON has no NaN: the invalid one as a string.
                "vel": [v if math.isfinite(v) else str(v) for v in vel],
                "var": var,
                "invalid": what,
            }
        )
        if what != "older":
            prev_stamp = stamp
    # Let the last messages leave before the participant goes.
    time.sleep(0.5)
    with open(a.out, "w") as f:
        json.dump(published, f)
    print(
        f"odometry publisher: {len(published)} messages on rt/{a.topic.strip('/')}, "
        f"{len(INVALID)} invalid",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
