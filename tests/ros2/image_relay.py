"""A camera driver's topics as Cyclone DDS publishes them, for easyhec's tests: relays
rt/sim/image_raw and rt/sim/camera_info (what `easyhec sim-camera` renders) to
rt/camera/color/image_raw and rt/camera/color/camera_info, re-encoding each image as bgr8 (the
encoding of many ROS 2 camera drivers) and keeping its stamp.

  image_relay.py DOMAIN
"""

import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_types import CameraInfo, Image


def main():
    participant = DomainParticipant(int(sys.argv[1]))
    reliable = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(2))
    # Sensor-data QoS on the driver side, as camera drivers publish.
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(2))

    def pair(name, kind, qos_in, qos_out):
        reader = DataReader(participant, Topic(participant, "rt/sim/" + name, kind, qos=qos_in), qos=qos_in)
        writer = DataWriter(participant, Topic(participant, "rt/camera/color/" + name, kind, qos=qos_out), qos=qos_out)
        return reader, writer

    images, images_out = pair("image_raw", Image, reliable, sensor)
    infos, infos_out = pair("camera_info", CameraInfo, reliable, sensor)
    print("relay up", flush=True)
    while True:
        for info in infos.take(N=4):
            infos_out.write(info)
        for m in images.take(N=4):
            assert m.encoding == "rgb8", m.encoding
            rgb = bytes(m.data)
            bgr = bytearray(rgb)
            bgr[0::3], bgr[2::3] = rgb[2::3], rgb[0::3]
            m.encoding, m.data = "bgr8", bgr
            images_out.write(m)
        time.sleep(0.005)


if __name__ == "__main__":
    sys.exit(main())
