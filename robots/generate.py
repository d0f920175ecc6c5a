#!/usr/bin/env python3
"""Writes robots/<name>/robot.urdf: published kinematics (joint origins, axes, limits: facts from
the manufacturers' documentation and ROS descriptions) with simple geometry of our own — a
cylinder per link segment and a housing per joint — so the simulated cell runs on any machine.
Run from this folder: python3 generate.py"""
import math, os

def rot_z_to(d):
    """rpy (URDF fixed-axis XYZ) of a rotation taking +z to unit vector d."""
    n = math.sqrt(sum(c * c for c in d))
    z = [c / n for c in d]
    helper = [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0]
    x = [helper[1] * z[2] - helper[2] * z[1], helper[2] * z[0] - helper[0] * z[2], helper[0] * z[1] - helper[1] * z[0]]
    xn = math.sqrt(sum(c * c for c in x)); x = [c / xn for c in x]
    y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]]
    R = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
    pitch = math.asin(max(-1.0, min(1.0, -R[2][0])))
    if abs(R[2][0]) < 1.0 - 1e-9:
        roll = math.atan2(R[2][1], R[2][2]); yaw = math.atan2(R[1][0], R[0][0])
    else:
        roll = math.atan2(-R[1][2], R[1][1]); yaw = 0.0
    return roll, pitch, yaw

def fmt(v):
    return " ".join(f"{c:.9g}" for c in v)

def cylinder(xyz, rpy, radius, length):
    g = f'<geometry><cylinder radius="{radius:.4g}" length="{length:.6g}"/></geometry>'
    o = f'<origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/>'
    return f"    <visual>{o}{g}</visual>\n    <collision>{o}{g}</collision>\n"

def write(name, links, joints, radius, housing):
    """links: names; joints: (name, type, parent, child, xyz, rpy, axis, lower, upper, velocity, mimic)."""
    children = {}
    for j in joints:
        children.setdefault(j[2], []).append(j)
    out = [f'<?xml version="1.0"?>\n<!-- {name}: published kinematics with simple geometry authored for easyhec (robots/generate.py). -->\n<robot name="{name}">\n']
    for l in links:
        body = ""
        r = radius.get(l)
        if r:
            h = housing.get(l, (r * 1.15, r * 2.2))
            # The first body (the base) stands on the floor instead of straddling it.
            lift = h[1] / 2 if l == next(n for n in links if n in radius) else 0.0
            body += cylinder([0, 0, lift], [0, 0, 0], h[0], h[1])
            for j in children.get(l, []):
                d = j[4]
                length = math.sqrt(sum(c * c for c in d))
                if length > 1e-6:
                    body += cylinder([c / 2 for c in d], rot_z_to(d), r, length)
        out.append(f'  <link name="{l}">\n{body}  </link>\n' if body else f'  <link name="{l}"/>\n')
    for (jn, jt, p, c, xyz, rpy, axis, lo, hi, vel, mimic) in joints:
        s = f'  <joint name="{jn}" type="{jt}">\n    <parent link="{p}"/>\n    <child link="{c}"/>\n    <origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/>\n'
        if jt != "fixed":
            s += f'    <axis xyz="{fmt(axis)}"/>\n    <limit lower="{lo}" upper="{hi}" effort="100" velocity="{vel}"/>\n'
        if mimic:
            s += f'    <mimic joint="{mimic}" multiplier="1" offset="0"/>\n'
        out.append(s + "  </joint>\n")
    out.append("</robot>\n")
    os.makedirs(name, exist_ok=True)
    with open(os.path.join(name, "robot.urdf"), "w") as f:
        f.write("".join(out))

H = math.pi / 2
TAU = 2 * math.pi

# UFACTORY xArm6: joint origins from the xArm user manual / xarm_ros kinematics.
write("xarm6",
      ["world", "link_base", "link1", "link2", "link3", "link4", "link5", "link6", "link_eef"],
      [("world_joint", "fixed", "world", "link_base", [0, 0, 0], [0, 0, 0], None, 0, 0, 0, None),
       ("joint1", "revolute", "link_base", "link1", [0, 0, 0.267], [0, 0, 0], [0, 0, 1], -TAU, TAU, 3.14, None),
       ("joint2", "revolute", "link1", "link2", [0, 0, 0], [-1.5708, 0, 0], [0, 0, 1], -2.059, 2.0944, 3.14, None),
       ("joint3", "revolute", "link2", "link3", [0.0535, -0.2845, 0], [0, 0, 0], [0, 0, 1], -3.927, 0.19198, 3.14, None),
       ("joint4", "revolute", "link3", "link4", [0.0775, 0.3425, 0], [-1.5708, 0, 0], [0, 0, 1], -TAU, TAU, 3.14, None),
       ("joint5", "revolute", "link4", "link5", [0, 0, 0], [1.5708, 0, 0], [0, 0, 1], -1.69297, math.pi, 3.14, None),
       ("joint6", "revolute", "link5", "link6", [0.076, 0.097, 0], [-1.5708, 0, 0], [0, 0, 1], -TAU, TAU, 3.14, None),
       ("joint_eef", "fixed", "link6", "link_eef", [0, 0, 0], [0, 0, 0], None, 0, 0, 0, None)],
      {"link_base": 0.06, "link1": 0.05, "link2": 0.045, "link3": 0.045, "link4": 0.04, "link5": 0.038, "link6": 0.035},
      {"link_base": (0.065, 0.2), "link6": (0.04, 0.03)})

# Universal Robots UR5e: DH parameters from UR's published kinematics.
write("ur5e",
      ["world", "base_link", "base_link_inertia", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
       "wrist_2_link", "wrist_3_link", "ft_frame", "base", "flange", "tool0"],
      [("base_joint", "fixed", "world", "base_link", [0, 0, 0], [0, 0, 0], None, 0, 0, 0, None),
       ("base_link-base_link_inertia", "fixed", "base_link", "base_link_inertia", [0, 0, 0], [0, 0, math.pi], None, 0, 0, 0, None),
       ("shoulder_pan_joint", "revolute", "base_link_inertia", "shoulder_link", [0, 0, 0.1625], [0, 0, 0], [0, 0, 1], -TAU, TAU, math.pi, None),
       ("shoulder_lift_joint", "revolute", "shoulder_link", "upper_arm_link", [0, 0, 0], [H, 0, 0], [0, 0, 1], -TAU, TAU, math.pi, None),
       ("elbow_joint", "revolute", "upper_arm_link", "forearm_link", [-0.425, 0, 0], [0, 0, 0], [0, 0, 1], -math.pi, math.pi, math.pi, None),
       ("wrist_1_joint", "revolute", "forearm_link", "wrist_1_link", [-0.3922, 0, 0.1333], [0, 0, 0], [0, 0, 1], -TAU, TAU, math.pi, None),
       ("wrist_2_joint", "revolute", "wrist_1_link", "wrist_2_link", [0, -0.0997, 0], [H, 0, 0], [0, 0, 1], -TAU, TAU, math.pi, None),
       ("wrist_3_joint", "revolute", "wrist_2_link", "wrist_3_link", [0, 0.0996, 0], [H, math.pi, math.pi], [0, 0, 1], -TAU, TAU, math.pi, None),
       ("wrist_3_link-ft_frame", "fixed", "wrist_3_link", "ft_frame", [0, 0, 0], [math.pi, 0, 0], None, 0, 0, 0, None),
       ("base_link-base_fixed_joint", "fixed", "base_link", "base", [0, 0, 0], [0, 0, math.pi], None, 0, 0, 0, None),
       ("wrist_3-flange", "fixed", "wrist_3_link", "flange", [0, 0, 0], [0, -H, -H], None, 0, 0, 0, None),
       ("flange-tool0", "fixed", "flange", "tool0", [0, 0, 0], [H, 0, H], None, 0, 0, 0, None)],
      {"base_link_inertia": 0.075, "shoulder_link": 0.06, "upper_arm_link": 0.055, "forearm_link": 0.045,
       "wrist_1_link": 0.04, "wrist_2_link": 0.04, "wrist_3_link": 0.038},
      {"base_link_inertia": (0.075, 0.09), "wrist_3_link": (0.038, 0.04)})

# Franka Emika Panda: kinematics from Franka's published parameters; the hand as a box-like block.
write("panda",
      ["panda_link0", "panda_link1", "panda_link2", "panda_link3", "panda_link4", "panda_link5", "panda_link6",
       "panda_link7", "panda_link8", "panda_hand", "panda_hand_tcp", "panda_leftfinger", "panda_rightfinger"],
      [("panda_joint1", "revolute", "panda_link0", "panda_link1", [0, 0, 0.333], [0, 0, 0], [0, 0, 1], -2.8973, 2.8973, 2.175, None),
       ("panda_joint2", "revolute", "panda_link1", "panda_link2", [0, 0, 0], [-H, 0, 0], [0, 0, 1], -1.7628, 1.7628, 2.175, None),
       ("panda_joint3", "revolute", "panda_link2", "panda_link3", [0, -0.316, 0], [H, 0, 0], [0, 0, 1], -2.8973, 2.8973, 2.175, None),
       ("panda_joint4", "revolute", "panda_link3", "panda_link4", [0.0825, 0, 0], [H, 0, 0], [0, 0, 1], -3.0718, -0.0698, 2.175, None),
       ("panda_joint5", "revolute", "panda_link4", "panda_link5", [-0.0825, 0.384, 0], [-H, 0, 0], [0, 0, 1], -2.8973, 2.8973, 2.61, None),
       ("panda_joint6", "revolute", "panda_link5", "panda_link6", [0, 0, 0], [H, 0, 0], [0, 0, 1], -0.0175, 3.7525, 2.61, None),
       ("panda_joint7", "revolute", "panda_link6", "panda_link7", [0.088, 0, 0], [H, 0, 0], [0, 0, 1], -2.8973, 2.8973, 2.61, None),
       ("panda_joint8", "fixed", "panda_link7", "panda_link8", [0, 0, 0.107], [0, 0, 0], None, 0, 0, 0, None),
       ("panda_hand_joint", "fixed", "panda_link8", "panda_hand", [0, 0, 0], [0, 0, -math.pi / 4], None, 0, 0, 0, None),
       ("panda_hand_tcp_joint", "fixed", "panda_hand", "panda_hand_tcp", [0, 0, 0.1034], [0, 0, 0], None, 0, 0, 0, None),
       ("panda_finger_joint1", "prismatic", "panda_hand", "panda_leftfinger", [0, 0, 0.0584], [0, 0, 0], [0, 1, 0], 0.0, 0.04, 0.2, None),
       ("panda_finger_joint2", "prismatic", "panda_hand", "panda_rightfinger", [0, 0, 0.0584], [0, 0, 0], [0, -1, 0], 0.0, 0.04, 0.2, "panda_finger_joint1")],
      {"panda_link0": 0.07, "panda_link1": 0.06, "panda_link2": 0.06, "panda_link3": 0.055, "panda_link4": 0.055,
       "panda_link5": 0.05, "panda_link6": 0.045, "panda_link7": 0.04, "panda_hand": 0.03,
       "panda_leftfinger": 0.01, "panda_rightfinger": 0.01},
      {"panda_link0": (0.08, 0.12), "panda_hand": (0.03, 0.2), "panda_leftfinger": (0.012, 0.05), "panda_rightfinger": (0.012, 0.05)})
