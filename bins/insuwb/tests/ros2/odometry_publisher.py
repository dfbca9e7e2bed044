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

import math
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic
from cyclonedds.util import duration

import publish
from ros_types import (
    Header,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
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
    a = publish.arguments("/wheel/odom", 150, 50.0)

    dp = DomainParticipant(a.domain)
    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
    )
    topic = Topic(dp, publish.dds_topic(a), Odometry)
    writer = DataWriter(dp, topic, qos=qos)

    if not publish.wait_matched(writer, a, "odometry publisher"):
        return 2

    published = []
    prev_stamp = None
    for k in publish.paced(a):
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
                stamp=publish.ros_time(stamp),
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
                "vel": publish.json_numbers(vel),
                "var": var,
                "invalid": what,
            }
        )
        if what != "older":
            prev_stamp = stamp
    publish.finish(a, published, "odometry publisher", "messages", len(INVALID))
    return 0


if __name__ == "__main__":
    sys.exit(main())
