"""What the ROS 2 publisher stand-ins share (PyPI `cyclonedds`, nothing of
insuwb): their command line, the bounded wait for a reader, the pacing by
the monotonic clock, ROS stamps, and the JSON of what they published.
"""

import argparse
import json
import math
import sys
import time

from ros_types import Time


def arguments(example_topic, count, rate):
    """The command line: --domain, --topic, --count, --rate, --match-timeout,
    --settle, --out, and --range-topic (a second topic, for the scripts that
    publish ranges beside)."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--topic", required=True, help=f"ROS topic, e.g. {example_topic}")
    ap.add_argument("--count", type=int, default=count)
    ap.add_argument("--rate", type=float, default=rate)
    ap.add_argument("--match-timeout", type=float, default=30.0)
    ap.add_argument("--settle", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--range-topic", default="", help="ROS topic of ranges, e.g. /flow/range")
    return ap.parse_args()


def dds_topic(a, topic=None):
    """The DDS topic of ROS topic `topic` (default --topic): `rt/<name>`."""
    return "rt/" + (topic or a.topic).strip("/")


def wait_matched(writer, a, who):
    """Bounded wait (--match-timeout) for the insuwb reader, then --settle
    for its side of the discovery (a best-effort reader loses a message
    sent before that). False when none matched."""
    deadline = time.monotonic() + a.match_timeout
    while not writer.get_matched_subscriptions():
        if time.monotonic() > deadline:
            print(f"{who}: no reader matched", file=sys.stderr, flush=True)
            return False
        time.sleep(0.01)
    time.sleep(a.settle)
    return True


def paced(a):
    """Indices 0..--count, each at its time at --rate Hz by the monotonic
    clock."""
    period = 1.0 / a.rate
    start = time.monotonic()
    for k in range(a.count):
        delay = start + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield k


def ros_time(ns):
    """A ROS `Time` of nanoseconds."""
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def json_numbers(values):
    """JSON has no NaN or infinity: those as strings."""
    return [v if math.isfinite(v) else str(v) for v in values]


def finish(a, published, who, what, invalid):
    """Lets the last messages leave, writes `published` to --out as JSON."""
    time.sleep(0.5)
    with open(a.out, "w") as f:
        json.dump(published, f)
    print(f"{who}: {len(published)} {what} on {dds_topic(a)}, {invalid} invalid", flush=True)
