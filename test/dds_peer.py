"""The other process of test_dds's two-process test: echo one MarkerArray and reply with a String.

Usage: python test/dds_peer.py DOMAIN_ID TIMEOUT_S. Exit codes: 0 done, 2 the test process's
readers never matched, 3 nothing arrived; every wait is bounded by TIMEOUT_S.
"""

import sys

from advperc_ros.ros import messages as msgs
from advperc_ros.ros.dds import DdsTransport
from advperc_ros.ros.topics import PERCEPTION, SUMMARY, TOPIC_TYPES, TRACKING


def main(domain_id: int, timeout: float) -> int:
    with DdsTransport(domain_id, localhost_only=True) as transport:
        objects = transport.subscriber(PERCEPTION, TOPIC_TYPES[PERCEPTION])
        echo = transport.publisher(TRACKING, TOPIC_TYPES[TRACKING])
        reply = transport.publisher(SUMMARY, TOPIC_TYPES[SUMMARY])
        if not (echo.wait_for_subscribers(1, timeout) and reply.wait_for_subscribers(1, timeout)):
            return 2
        received = objects.wait(timeout)
        if not received:
            return 3
        echo.publish(received[0])
        reply.publish(msgs.string(f"received {len(received[0].markers)} markers"))
        # deleting the participant right away could drop data not yet acknowledged
        echo.wait_for_acks(timeout)
        reply.wait_for_acks(timeout)
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), float(sys.argv[2])))
