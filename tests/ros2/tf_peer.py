"""An independent ROS 2 tf peer for easyhec's tests, on Eclipse Cyclone DDS (PyPI `cyclonedds`,
which ships its own library): the same wire types a ROS 2 node uses, with no ROS installed.

  tf_peer.py listen DOMAIN SECONDS [CHILD]
      Subscribes to rt/tf_static as tf2's listener does (reliable, transient local) and prints
      the first TFMessage (with an edge to CHILD, when given) as one JSON line; exits 1 if none
      arrives in SECONDS.
  tf_peer.py latch DOMAIN PARENT CHILD X Y Z QX QY QZ QW [PARENT CHILD X ... QW]...
      Latches those edges on rt/tf_static, as a camera driver's static broadcaster does, and
      prints "latched" once written; runs until killed.
  tf_peer.py broadcast DOMAIN PARENT CHILD X Y Z QX QY QZ QW ...
      Sends those edges on rt/tf at 20 Hz, as a moving frame's broadcaster does (reliable,
      volatile, depth 100), printing "broadcasting" once; runs until killed.
"""

import json
import sys
import time
from dataclasses import asdict

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_types import Header, Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3


STATIC_QOS = Qos(
    Policy.Reliability.Reliable(duration(seconds=1)),
    Policy.Durability.TransientLocal,
    Policy.History.KeepLast(1),
)


def tf_static(domain):
    participant = DomainParticipant(domain)
    return participant, Topic(participant, "rt/tf_static", TFMessage, qos=STATIC_QOS)


def listen(domain, seconds, child):
    participant, topic = tf_static(domain)
    reader = DataReader(participant, topic, qos=STATIC_QOS)
    deadline = time.time() + seconds
    while time.time() < deadline:
        for sample in reader.take(N=10):
            if child is None or any(t.child_frame_id == child for t in sample.transforms):
                print(json.dumps(asdict(sample)), flush=True)
                return 0
        time.sleep(0.02)
    print("no TFMessage on rt/tf_static", file=sys.stderr)
    return 1


def edges_of(words):
    edges = []
    for i in range(0, len(words), 9):
        parent, child, *numbers = words[i : i + 9]
        x, y, z, qx, qy, qz, qw = (float(v) for v in numbers)
        edges.append(
            TransformStamped(
                Header(Time(0, 0), parent),
                child,
                Transform(Vector3(x, y, z), Quaternion(qx, qy, qz, qw)),
            )
        )
    return edges


def latch(domain, words):
    participant, topic = tf_static(domain)
    writer = DataWriter(participant, topic, qos=STATIC_QOS)
    edges = edges_of(words)
    writer.write(TFMessage(edges))
    print("latched", flush=True)
    while True:
        time.sleep(1)


def broadcast(domain, words):
    participant = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(100))
    writer = DataWriter(participant, Topic(participant, "rt/tf", TFMessage, qos=qos), qos=qos)
    edges = edges_of(words)
    print("broadcasting", flush=True)
    while True:
        writer.write(TFMessage(edges))
        time.sleep(0.05)


def main():
    mode, domain = sys.argv[1], int(sys.argv[2])
    if mode == "listen":
        return listen(domain, float(sys.argv[3]), sys.argv[4] if len(sys.argv) > 4 else None)
    if mode == "latch":
        return latch(domain, sys.argv[3:])
    if mode == "broadcast":
        return broadcast(domain, sys.argv[3:])
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
