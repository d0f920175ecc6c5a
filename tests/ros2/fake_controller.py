"""A fake ros2_control joint_trajectory_controller on Cyclone DDS, for easyhec's tests: it
publishes rt/joint_states at 100 Hz and follows trajectory_msgs/JointTrajectory commands on
rt/joint_trajectory_controller/joint_trajectory, moving linearly from where the joints are to
the (single) point over its time_from_start, as the real controller does with positions only.
An empty trajectory is refused and logged, as current controllers refuse it.

  fake_controller.py DOMAIN NAMES START LOG [--silent-after SECONDS]

NAMES and START are comma-separated. Every command is appended to LOG as one JSON line: the
seconds since start, the joints it started from, the last point's positions and time, the
point count, whether any point carried velocities, accelerations or efforts, and the header
stamp. With --silent-after, joint states stop after that
many seconds (a controller that died).
"""

import json
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_types import Header, JointState, JointTrajectory, Time

RATE_HZ = 100.0


def main():
    domain, names, start, log_path = int(sys.argv[1]), sys.argv[2].split(","), sys.argv[3], sys.argv[4]
    silent_after = float(sys.argv[6]) if len(sys.argv) > 6 and sys.argv[5] == "--silent-after" else None
    q = [float(v) for v in start.split(",")]
    assert len(q) == len(names)
    participant = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
    states = DataWriter(participant, Topic(participant, "rt/joint_states", JointState, qos=qos), qos=qos)
    commands = DataReader(
        participant,
        Topic(participant, "rt/joint_trajectory_controller/joint_trajectory", JointTrajectory, qos=qos),
        qos=qos,
    )
    segment = None  # (from, to, t0, duration)
    began = time.time()
    with open(log_path, "a") as log:
        print("controller up", flush=True)
        while True:
            now = time.time()
            for m in commands.take(N=10):
                if not m.points:
                    log.write(json.dumps({"t": now - began, "rejected": "empty trajectory"}) + "\n")
                    log.flush()
                    continue
                order = [m.joint_names.index(n) for n in names]
                target = [m.points[-1].positions[i] for i in order]
                t = m.points[-1].time_from_start.sec + m.points[-1].time_from_start.nanosec * 1e-9
                extras = any(p.velocities or p.accelerations or p.effort for p in m.points)
                stamp = [m.header.stamp.sec, m.header.stamp.nanosec]
                log.write(
                    json.dumps(
                        {"t": now - began, "from": q, "to": target, "time_s": t,
                         "points": len(m.points), "extras": extras, "stamp": stamp}
                    )
                    + "\n"
                )
                log.flush()
                segment = (list(q), target, now, max(t, 1e-3))
            if segment is not None:
                a, b, t0, d = segment
                s = min(1.0, (now - t0) / d)
                q = [x + (y - x) * s for x, y in zip(a, b)]
                if s >= 1.0:
                    segment = None
            if silent_after is None or now - began < silent_after:
                secs = int(now)
                states.write(
                    JointState(Header(Time(secs, int((now - secs) * 1e9)), ""), names, q, [], [])
                )
            time.sleep(1.0 / RATE_HZ)


if __name__ == "__main__":
    sys.exit(main())
