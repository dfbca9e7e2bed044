"""A fleet client on the PyPI eclipse-zenoh package (no insuwb code) that
speaks for a robot of its choosing: it connects to a station over TLS with
the certificate and key it is given (or none), then puts --count
well-formed health reports (the fleet's JSON health payload, its encoding
and attachment, blocking congestion control) under insuwb/<--as>/health.

Writes one JSON object to --out: `connected` (whether the session opened),
`matched` (whether the station's subscriber matched within
--match-timeout: a router that refuses everything of this peer never
declares it), `sent` (the puts made).
"""

import argparse
import json
import os
import sys
import time

import zenoh

# The fleet's health payload and attachment, as the hostile peer writes them.
from hostile_peer import HEALTH, attachment, health_json  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True, help="e.g. tls/127.0.0.1:7447")
    ap.add_argument("--ca", required=True)
    ap.add_argument("--cert", help="client certificate (none: connect without one)")
    ap.add_argument("--key")
    ap.add_argument("--as", dest="robot", required=True, help="the robot id to put under")
    ap.add_argument("--count", type=int, default=60)
    ap.add_argument("--match-timeout", type=float, default=10.0)
    ap.add_argument("--linger", type=float, default=1.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(a.ca))
    if a.cert:
        conf.insert_json5("transport/link/tls/connect_certificate", json.dumps(a.cert))
        conf.insert_json5("transport/link/tls/connect_private_key", json.dumps(a.key))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    result = {"connected": False, "matched": False, "sent": 0}
    try:
        s = zenoh.open(conf)
    except Exception as e:  # the station refused the handshake
        print(f"open failed: {e}", file=sys.stderr)
        with open(a.out, "w") as f:
            json.dump(result, f)
        return 0
    result["connected"] = True
    key = f"insuwb/{a.robot}/health"
    pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    t0 = time.monotonic()
    while not pub.matching_status.matching and time.monotonic() - t0 < a.match_timeout:
        time.sleep(0.05)
    result["matched"] = pub.matching_status.matching
    for i in range(a.count):
        pub.put(
            health_json(a.robot, time.monotonic_ns()),
            encoding=zenoh.Encoding(HEALTH),
            attachment=attachment(i),
        )
        result["sent"] += 1
        time.sleep(0.01)
    time.sleep(a.linger)
    with open(a.out, "w") as f:
        json.dump(result, f)
    # The session is left to the process's exit (closing it can block).
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
