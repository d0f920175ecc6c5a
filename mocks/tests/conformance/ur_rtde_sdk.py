"""Vendor-SDK conformance scenario for the mock UR controller.

Runs ur_rtde (1.6.5, SDU Robotics) against a controller at HOST; ur_rtde has no port options,
so the controller must listen on 30004 (RTDE), 29999 (dashboard) and 30003 (script) there:

    python3 ur_rtde_sdk.py HOST move START_J1,...,J6 TARGET_J1,...,J6 SPEED ACCEL
    python3 ur_rtde_sdk.py HOST local-control

`move`: RTDEReceiveInterface with an explicit and with the default recipe, the dashboard
client, RTDEControlInterface (script upload and register handshake), a synchronous moveJ to
TARGET, an asynchronous moveJ back to START interrupted by stopJ, then stopScript and
disconnect. `local-control`: RTDEControlInterface must refuse a controller that is not in
remote control. Prints one line `OK ...` on success; any failure exits non-zero.
"""

import sys
import time


def fail(code, msg):
    print("FAIL: " + msg, file=sys.stderr, flush=True)
    sys.exit(code)


def close(a, b, tol):
    return len(a) == len(b) and max(abs(x - y) for x, y in zip(a, b)) <= tol


def wait_for(pred, timeout_s):
    end = time.time() + timeout_s
    while time.time() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def move(host, start, target, speed, accel):
    import dashboard_client
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(
        host, 125.0, ["actual_q", "robot_mode", "safety_mode", "runtime_state", "timestamp"]
    )
    if not r.isConnected():
        fail(2, "receive interface not connected")
    q = r.getActualQ()
    if not close(q, start, 1e-9):
        fail(3, f"actual_q {q} is not the start pose {start}")
    if r.getRobotMode() != 7 or r.getSafetyMode() != 1:
        fail(3, f"robot mode {r.getRobotMode()}, safety mode {r.getSafetyMode()}")

    # The default recipe: every variable ur_rtde knows for controller 5.11.
    full = rtde_receive.RTDEReceiveInterface(host)
    if not close(full.getActualQ(), start, 1e-9) or full.getSafetyStatusBits() != 1:
        fail(3, f"default recipe: {full.getActualQ()}, bits {full.getSafetyStatusBits()}")
    full.disconnect()

    d = dashboard_client.DashboardClient(host)
    d.connect()
    version = d.polyscopeVersion()
    mode = d.robotmode()
    safety = d.safetystatus()
    remote = d.isInRemoteControl()
    if "5.11.1" not in version or "RUNNING" not in mode or "NORMAL" not in safety or not remote:
        fail(4, f"dashboard: {version!r} {mode!r} {safety!r} remote={remote}")
    d.disconnect()

    c = rtde_control.RTDEControlInterface(host)
    if not c.isConnected() or not c.isProgramRunning():
        fail(5, "control interface not connected or its script not running")

    if not c.moveJ(target, speed, accel):
        fail(6, "moveJ returned False")
    if not wait_for(lambda: close(r.getActualQ(), target, 1e-9), 1.0):
        fail(6, f"after moveJ actual_q {r.getActualQ()} is not {target}")

    if not c.moveJ(start, speed, accel, True):
        fail(7, "asynchronous moveJ returned False")
    if not c.getAsyncOperationProgressEx().isAsyncOperationRunning():
        fail(7, "asynchronous moveJ not reported running")
    time.sleep(0.1)
    c.stopJ(2.0)
    status = c.getAsyncOperationProgressEx()
    if status.isAsyncOperationRunning():
        fail(8, "still running after stopJ")
    time.sleep(0.1)
    q1 = r.getActualQ()
    time.sleep(0.1)
    q2 = r.getActualQ()
    if not close(q1, q2, 1e-12) or close(q2, start, 1e-3) or close(q2, target, 1e-3):
        fail(8, f"after stopJ the arm should stand between target and start: {q1} {q2}")

    c.stopScript()
    c.disconnect()
    r.disconnect()
    if c.isConnected() or r.isConnected():
        fail(9, "still connected after disconnect")
    print("OK " + ",".join(f"{v:.6f}" for v in q2), flush=True)


def local_control(host):
    import rtde_control

    try:
        rtde_control.RTDEControlInterface(host)
    except RuntimeError as e:
        if "remote control" in str(e):
            print("OK refused: " + str(e), flush=True)
            return
        fail(10, f"unexpected error: {e}")
    fail(10, "RTDEControlInterface connected to a controller in local control")


def main():
    host, scenario = sys.argv[1], sys.argv[2]
    if scenario == "move":
        start = [float(v) for v in sys.argv[3].split(",")]
        target = [float(v) for v in sys.argv[4].split(",")]
        move(host, start, target, float(sys.argv[5]), float(sys.argv[6]))
    elif scenario == "local-control":
        local_control(host)
    else:
        fail(1, f"unknown scenario {scenario}")


if __name__ == "__main__":
    main()
