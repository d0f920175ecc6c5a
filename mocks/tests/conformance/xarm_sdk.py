"""Vendor-SDK conformance scenario for the mock xArm controller.

Runs xarm-python-sdk (1.18.4) against a controller at HOST with the command port and the
normal (30001-style) report port given on the command line:

    python3 xarm_sdk.py HOST COMMAND_PORT NORMAL_REPORT_PORT J1,J2,...  SPEED_RAD_S

The SDK hard-codes its ports (XCONF.SocketConf) and picks the report layout by comparing the
port number with 30001..30003, so this script patches both, here only, before connecting.
Prints one line `OK <joints>` on success; any failure exits non-zero with a message.
"""

import math
import sys


def main() -> int:
    host, command_port, report_port = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    target = [float(v) for v in sys.argv[4].split(",")]
    speed = float(sys.argv[5])

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

    arm = XArmAPI(host, is_radian=True, report_type="normal", check_joint_limit=True)
    try:
        if not arm.connected:
            print("FAIL: the SDK could not connect", file=sys.stderr)
            return 2
        print("version", arm.version, "axis", arm.axis, "type", arm.device_type, flush=True)
        steps = [
            ("motion_enable", arm.motion_enable(enable=True)),
            ("set_mode", arm.set_mode(0)),
            ("set_state", arm.set_state(state=0)),
        ]
        for name, code in steps:
            if code != 0:
                print(f"FAIL: {name} returned {code}", file=sys.stderr)
                return 3
        code = arm.set_servo_angle(angle=target, is_radian=True, speed=speed, wait=True)
        if code != 0:
            print(f"FAIL: set_servo_angle returned {code}", file=sys.stderr)
            return 4
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
