"""An independent ROS 2 tf peer for easyhec's tests, on Eclipse Cyclone DDS (PyPI `cyclonedds`,
which ships its own library): the same wire types a ROS 2 node uses, with no ROS installed.

  tf_peer.py listen DOMAIN SECONDS [CHILD]
      Subscribes to rt/tf_static as tf2's listener does (reliable, transient local) and prints
      the first TFMessage (with an edge to CHILD, when given) as one JSON line; exits 1 if none
      arrives in SECONDS.
  tf_peer.py latch DOMAIN PARENT CHILD X Y Z QX QY QZ QW [PARENT CHILD X ... QW]...
      Latches those edges on rt/tf_static, as a camera driver's static broadcaster does, and
      prints "latched" once written; runs until killed.
"""

import json
import sys
import time
from dataclasses import asdict, dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


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


def latch(domain, words):
    participant, topic = tf_static(domain)
    writer = DataWriter(participant, topic, qos=STATIC_QOS)
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
    writer.write(TFMessage(edges))
    print("latched", flush=True)
    while True:
        time.sleep(1)


def main():
    mode, domain = sys.argv[1], int(sys.argv[2])
    if mode == "listen":
        return listen(domain, float(sys.argv[3]), sys.argv[4] if len(sys.argv) > 4 else None)
    if mode == "latch":
        return latch(domain, sys.argv[3:])
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
