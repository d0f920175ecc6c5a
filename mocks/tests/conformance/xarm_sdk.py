"""Vendor-SDK conformance scenarios for the mock xArm controller.

Runs xarm-python-sdk (1.18.4) against a controller at HOST, in one of two ways:

    python3 xarm_sdk.py HOST COMMAND_PORT NORMAL_REPORT_PORT J1,J2,...  SPEED_RAD_S
    python3 xarm_sdk.py --default-constructor HOST J1,J2,...  SPEED_RAD_S

The first takes the command port and the normal (30001-style) report port from the command
line. The SDK hard-codes its ports (XCONF.SocketConf) and picks the report layout by comparing
the port number with 30001..30003, so this script patches both, here only, before connecting,
and asks for report_type='normal'.

The second patches nothing and calls `XArmAPI(HOST)` exactly as a user's first script does: the
command port 502 and the rich report on 30002. After the move it waits for the next two
reports, so the angles it prints come from a frame pushed after the arrival, and so that the
rich fields that frame carries have been parsed too (the SDK parses them after calling the
report callbacks). It then prints `REPORTED <joints>` (rad) and
`RICH <key>=<value> ...` for the caller to compare with the mock's state.

Both print one line `OK <joints>` on success; any failure exits non-zero with a message. Steps
that can block (the SDK never times out on a silent peer) are announced on stdout first, so
the caller's kill timeout leaves a trail of where it stopped.
"""

import math
import sys
import threading


def step(text: str) -> None:
    print("step:", text, flush=True)


def connect_patched(host: str, command_port: int, report_port: int):
    from xarm.core.config.x_config import XCONF
    from xarm.x3.report import ReportDataStructure

    XCONF.SocketConf.TCP_CONTROL_PORT = command_port
    XCONF.SocketConf.TCP_REPORT_NORM_PORT = report_port
    canonical = {report_port: 30001}
    original_create = ReportDataStructure.create.__func__
    ReportDataStructure.create = classmethod(
        lambda cls, port, **kw: original_create(cls, canonical.get(port, port), **kw)
    )

    from xarm.wrapper import XArmAPI

    return XArmAPI(host, is_radian=True, report_type="normal", check_joint_limit=True)


class Reports:
    """Counts the report frames the SDK hands to its report callbacks."""

    def __init__(self):
        self.cond = threading.Condition()
        self.count = 0
        self.last = None

    def __call__(self, msg):
        with self.cond:
            self.count += 1
            self.last = msg
            self.cond.notify_all()

    def wait_past(self, count: int):
        """The callback data of the first report after the `count`th; no deadline of its own."""
        with self.cond:
            self.cond.wait_for(lambda: self.count > count)
            return self.count, self.last


def main() -> int:
    args = sys.argv[1:]
    default = args[0] == "--default-constructor"
    reports = Reports()
    if default:
        host, joints, speed = args[1], args[2], args[3]
        from xarm.wrapper import XArmAPI

        step(f"XArmAPI({host!r})")
        arm = XArmAPI(host)
    else:
        host, command_port, report_port, joints, speed = args
        step(f"XArmAPI({host!r}) on ports {command_port}, {report_port}")
        arm = connect_patched(host, int(command_port), int(report_port))
    target = [float(v) for v in joints.split(",")]
    speed = float(speed)
    try:
        if not arm.connected:
            print("FAIL: the SDK could not connect", file=sys.stderr)
            return 2
        print("version", arm.version, "axis", arm.axis, "type", arm.device_type, flush=True)
        arm.register_report_callback(reports, report_cartesian=False, report_joints=True)
        steps = [
            ("motion_enable", lambda: arm.motion_enable(enable=True)),
            ("set_mode", lambda: arm.set_mode(0)),
            ("set_state", lambda: arm.set_state(state=0)),
        ]
        for name, call in steps:
            step(name)
            code = call()
            if code != 0:
                print(f"FAIL: {name} returned {code}", file=sys.stderr)
                return 3
        step("set_servo_angle(wait=True)")
        code = arm.set_servo_angle(angle=target, is_radian=True, speed=speed, wait=True)
        if code != 0:
            print(f"FAIL: set_servo_angle returned {code}", file=sys.stderr)
            return 4
        if default:
            # Angles from the report alone: get_servo_angle below would overwrite them with
            # a register read.
            step("waiting for two reports after the move")
            seen, _ = reports.wait_past(reports.count)
            _, last = reports.wait_past(seen)
            # The default constructor works in degrees.
            reported = [math.radians(v) for v in last["joints"][: len(target)]]
            print("REPORTED " + ",".join(f"{v:.6f}" for v in reported), flush=True)
            rich = {
                "report_type": arm._arm._report_type,  # what the default constructor chose
                "axis": arm.axis,
                "device_type": arm.device_type,
                "master_id": arm.master_id,
                "slave_id": arm.slave_id,
                "joint_speed_max": math.radians(arm.joint_speed_limit[1]),
                "joint_acc_max": math.radians(arm.joint_acc_limit[1]),
                "temperatures": ",".join(str(t) for t in arm.temperatures),
                "voltages": ",".join(f"{v:.2f}" for v in arm.voltages),
                "joint_speeds": ",".join(
                    f"{math.radians(v):.6f}" for v in arm.realtime_joint_speeds
                ),
                "mtable": ",".join(str(int(b)) for b in arm.motor_enable_states),
                "state": arm.state,
                "error": arm.error_code,
            }
            print("RICH " + " ".join(f"{k}={v}" for k, v in rich.items()), flush=True)
        step("get_servo_angle")
        code, angles = arm.get_servo_angle(is_radian=True)
        if code != 0:
            print(f"FAIL: get_servo_angle returned {code}", file=sys.stderr)
            return 5
        got = angles[: len(target)]
        worst = max(abs(a - b) for a, b in zip(got, target))
        if worst > 1e-4:
            print(f"FAIL: joints {got} differ from {target} by {worst}", file=sys.stderr)
            return 6
        if arm.error_code != 0 or arm.state not in (1, 2):
            print(f"FAIL: after the move error {arm.error_code}, state {arm.state}", file=sys.stderr)
            return 7
        print("OK " + ",".join(f"{v:.6f}" for v in got), flush=True)
        return 0
    finally:
        arm.disconnect()


if __name__ == "__main__":
    sys.exit(main())
