"""A ROS 2 wheel-odometry driver stand-in written with the PyPI `cyclonedds`
package (Eclipse Cyclone DDS, nothing of insuwb): publishes `nav_msgs/Odometry`
under its DDS type name `nav_msgs::msg::dds_::Odometry_` on `rt/<topic>`
(reliable, volatile, keep-last 10, as base drivers publish), stamped with the
real-time clock (ROS time), pose in `odom`, twist in `base_link`.

It waits (bounded) until a reader has matched, then publishes --count
messages at --rate Hz with known twists and twist covariances (per axis: a
variance, 0 for "unset", or 1e6 for "unknown"); a few are deliberately
invalid: a NaN velocity, a negative variance, and one stamped before its
predecessor. With --range-topic it also publishes, beside each, a
downward range finder's `sensor_msgs/Range` (`sensor_msgs::msg::dds_::Range_`,
infrared, limits 0.04-4 m, frame `range_down`) with a known range; four of
them are invalid: nothing in reach (+inf, REP 117), NaN, beyond the
sensor's 4 m, and one stamped before its predecessor. It writes what it
published as JSON: each message's stamp, linear velocity, variances of the
three linear axes (or its range) and whether a receiver should keep it.
Exit code 2 when no reader matched.
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
    Range,
    Twist,
    TwistWithCovariance,
    Vector3,
)


# Message index -> what is wrong with it.
INVALID = {30: "nan", 70: "negative", 110: "older"}
# Range index -> what is wrong with it.
INVALID_RANGE = {40: "inf", 80: "nan", 100: "beyond", 120: "older"}


def range_message(k, prev_stamp):
    """Range k (m) and its message, stamped now (or before `prev_stamp`),
    with what is wrong with it."""
    what = INVALID_RANGE.get(k)
    value = {"inf": math.inf, "nan": math.nan, "beyond": 4.5}.get(what, 0.3 + 0.01 * k)
    stamp = prev_stamp - 5_000_000 if what == "older" else time.time_ns()
    msg = Range(
        header=Header(stamp=publish.ros_time(stamp), frame_id="range_down"),
        radiation_type=1,
        field_of_view=0.47,
        min_range=0.04,
        max_range=4.0,
        range=value,
    )
    return msg, {"stamp_ns": stamp, "range": publish.json_numbers([value])[0], "invalid": what}


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
    ranges = None
    if a.range_topic:
        rtopic = Topic(dp, publish.dds_topic(a, a.range_topic), Range)
        ranges = DataWriter(dp, rtopic, qos=qos)
        if not publish.wait_matched(ranges, a, "range publisher"):
            return 2
    prev_range_stamp = None

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
        if ranges is not None:
            msg, sent = range_message(k, prev_range_stamp)
            ranges.write(msg)
            published.append(sent)
            if sent["invalid"] != "older":
                prev_range_stamp = sent["stamp_ns"]
    invalid = len(INVALID) + (len(INVALID_RANGE) if ranges is not None else 0)
    publish.finish(a, published, "odometry publisher", "messages", invalid)
    return 0


if __name__ == "__main__":
    sys.exit(main())
