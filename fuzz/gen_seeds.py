#!/usr/bin/env python3
"""Writes the seed corpora under fuzz/seeds/<target>/ from the test vectors of
protocols.md (§1.2-1.6 xArm, §2.2 RTDE, §3.2/§3.5 Dynamixel and Feetech, §4.3-4.4 Piper).

Run from anywhere: python3 fuzz/gen_seeds.py. Existing seed files are replaced.
"""

import math
import os
import struct

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "seeds")


def hx(s):
    return bytes.fromhex(s.replace(" ", ""))


def write(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


# --- xArm command port (§1.2, §1.3) -------------------------------------------------------
def xarm_frame(tid, proto, body):
    return struct.pack(">HHH", tid, proto, len(body)) + body


move = struct.pack("<10f", math.pi / 3, 0, 0, 0, 0, 0, 0,
                   math.radians(20), math.radians(500), 0)
joint_reply = xarm_frame(1, 2, b"\x2a\x00" + struct.pack("<7f", math.pi / 3, 0, 0, 0, 0, 0, 0))
version = b"6,6,XI1202,AC1302,v1.12.10".ljust(40, b"\0")
xarm = {
    "reply_motion_en": hx("00 01 00 02 00 02 0B 10"),
    "reply_get_state": hx("00 01 00 02 00 03 0D 00 02"),
    "reply_get_error": hx("00 01 00 02 00 04 0F 00 00 00"),
    "reply_move_joint": hx("00 01 00 02 00 04 17 00 00 01"),
    "reply_joint_pos": joint_reply,
    "reply_version": xarm_frame(1, 2, b"\x01\x00" + version),
    "request_motion_en": hx("00 01 00 02 00 03 0B 08 01"),
    "request_set_mode": hx("00 01 00 02 00 03 13 00 00"),
    "request_move_joint": xarm_frame(1, 2, b"\x17" + move),
    "heartbeat": hx("00 00 00 01 00 02 00 00"),
    "stream_feedback_then_reply": xarm_frame(7, 2, b"\xff\x00")
    + hx("00 01 00 03 00 03 0D 00 02")
    + hx("00 02 00 02 00 02 0C 00"),
}
for name, data in xarm.items():
    write("xarm_reply", name, data)


# --- xArm reports (§1.6) -----------------------------------------------------------------
def report(length, mode=0, state=2, header=None):
    body = bytes([(mode << 4) | state]) + struct.pack(">H", 3)
    body += struct.pack("<7f", 0.5, -0.25, -1.0, 0.0, 0.75, 0.125, 0.0)  # joints
    body += struct.pack("<6f", 207.0, 0.0, 112.0, math.pi, 0.0, 0.0)  # TCP pose
    body += struct.pack("<7f", *([0.0] * 7))  # torques
    if length >= 133:
        body += bytes([0x3F, 0x3F, 0, 0])
        body += struct.pack("<6f", *([0.0] * 6))  # TCP offset
        body += struct.pack("<4f", 0.5, 0.0, 0.0, 30.0)  # payload
        body += bytes([3, 3])
    if length >= 145:
        body += struct.pack("<3f", 0.0, 0.0, -1.0)
    body = body.ljust(length - 4, b"\0")
    return struct.pack(">I", length if header is None else header) + body


write("xarm_report", "real_87", report(87))
write("xarm_report", "normal_145", report(145, mode=1, state=1))
write("xarm_report", "normal_old_133", report(133))
write("xarm_report", "rich_233_quirk", report(245, header=233))
write("xarm_report", "stream_real_normal_real", report(87) + report(145) + report(87, state=4))


# --- RTDE (§2.2) ---------------------------------------------------------------------------
def pkg(kind, payload=b""):
    return struct.pack(">HB", len(payload) + 3, ord(kind)) + payload


rtde = {
    "v_request": hx("00 05 56 00 02"),
    "v_reply": hx("00 04 56 01"),
    "control_version_reply": hx("00 13 76 00000005 0000000B 00000001 0001A71E"),
    "o_request": hx("00 1E 4F 405F400000000000") + b"actual_q,robot_mode",
    "o_reply": hx("00 12 4F 01") + b"VECTOR6D,INT32",
    "s_request": hx("00 03 53"),
    "u_server": pkg("U", b"\x01" + struct.pack(">6d", 0.1, -0.2, 0.3, -0.4, 0.5, -0.6)
                    + struct.pack(">i", 7)),
    "client_session": pkg("V", b"\x00\x02")
    + pkg("O", struct.pack(">d", 125.0) + b"actual_q,robot_mode,")
    + pkg("I", b"input_int_register_0,input_double_register_1,input_bit_register_64")
    + pkg("S")
    + pkg("U", b"\x01" + struct.pack(">i", -3) + struct.pack(">d", 2.5) + b"\x01")
    + pkg("P"),
    "text_message": pkg("M", b"\x05hello\x04mock\x03"),
}
for name, data in rtde.items():
    write("rtde", name, data)

# --- Dynamixel 2.0 (§3.1, §3.2) ------------------------------------------------------------
dxl = {
    "ping": "FF FF FD 00 01 03 00 01 19 4E",
    "ping_reply": "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D",
    "broadcast_ping": "FF FF FD 00 FE 03 00 01 31 42",
    "read_present_position": "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    "read_reply": "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0",
    "write_goal_position": "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    "torque_enable": "FF FF FD 00 01 06 00 03 40 00 01 DB 66",
    "sync_read": "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
    "sync_write": "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
}
for name, s in dxl.items():
    write("dynamixel", name, hx(s))
write("dynamixel", "stream_noise_echo_replies",
      hx("00 13 FF") + hx(dxl["sync_read"]) + hx(dxl["read_reply"]) + hx(dxl["ping_reply"]))


def crc16(data):
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


# A write whose data holds FF FF FD: stuffed on the wire (length and CRC over stuffed bytes).
stuffed = hx("FF FF FD 00 01") + struct.pack("<H", 11) + hx("03 74 00 FF FF FD FD 00")
write("dynamixel", "stuffed_write", stuffed + struct.pack("<H", crc16(stuffed)))
write("dynamixel", "check_value_123456789", b"123456789")


# --- Feetech STS (§3.5) --------------------------------------------------------------------
def ft(pid, body):
    p = bytes([pid, len(body) + 1]) + body
    return b"\xff\xff" + p + bytes([~sum(p) & 0xFF])


write("feetech", "ping", hx("FF FF 01 02 01 FB"))
write("feetech", "read_present_position", hx("FF FF 01 04 02 38 02 BE"))
write("feetech", "status_overheat", ft(3, bytes([4, 0x00, 0x08])))
write("feetech", "read_reply", ft(1, bytes([0, 0x00, 0x08])))
write("feetech", "sync_write", ft(0xFE, bytes([0x83, 42, 2, 1, 0x00, 0x08, 2, 0xFF, 0x07])))
write("feetech", "stream_idle_noise_reply",
      hx("FF FF FF 00") + hx("FF FF 01 02 01 FB") + ft(1, bytes([0, 0x00, 0x08])))


# --- Piper CAN (§4.3, §4.4): records of id u16 BE, length, 8 data bytes --------------------
def can(cid, data):
    return struct.pack(">HB", cid, len(data)) + data.ljust(8, b"\0")


write("piper", "joint_target_155", can(0x155, hx("00 00 27 10 FF FF B1 E0")))
write("piper", "joint_feedback_2a5_2a7", can(0x2A5, hx("00 00 27 10 FF FF B1 E0"))
      + can(0x2A6, struct.pack(">ii", 3, -4)) + can(0x2A7, struct.pack(">ii", 5, 6)))
write("piper", "status_2a1_collision", can(0x2A1, hx("01 07 01 00 01 00 04 21")))
write("piper", "mode_enable_motion", can(0x151, hx("01 01 32 00 00 00 00 00"))
      + can(0x471, hx("07 02 00 00 00 00 00 00")) + can(0x150, hx("02 00 00 00 00 00 00 00")))
write("piper", "driver_state_261_266",
      b"".join(can(0x261 + k, struct.pack(">hhB", 240, 30, 30) + bytes([0x40, 0, 0]))
               for k in range(6)))
write("piper", "short_and_extended", can(0x2A5, b"\x01\x02") + can(0x1FFF, b""))
