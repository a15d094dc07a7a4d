"""The serialized (CDR, little-endian) layout of the standard messages nifo reads and writes.

``sensor_msgs/msg/Imu`` (spindle, body), ``geometry_msgs/msg/PointStamped``
(tire patch) and ``geometry_msgs/msg/WrenchStamped`` (a measured force on the
body, ``wrench.force.<axis>`` [N]): encapsulation ``00 01 00 00``, then ``std_msgs/Header`` (stamp
sec int32, nanosec uint32, frame_id as a CDR string) padded to 8 bytes, then a
fixed block of float64s. One place for that layout: the bag writer/reader
(:mod:`nifo.io.bag`) and the ROS nodes (:mod:`nifo_nodes.messages`) both use it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from nifo_core.errors import InputError

__all__ = ["IMU", "POINT_STAMPED", "WRENCH_STAMPED", "Axis", "AXES", "CDR_LE", "IMU_BODY", "IMU_VALUE", "POINT_BODY",
           "POINT_VALUE", "WRENCH_BODY", "WRENCH_VALUE", "LAYOUT", "header_size", "header", "payloads",
           "value_offset"]

IMU = "sensor_msgs/msg/Imu"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
Axis = Literal["x", "y", "z"]
AXES = {"x": 0, "y": 1, "z": 2}
CDR_LE = b"\x00\x01\x00\x00"
#: Imu after the 8-aligned header: orientation 4 + cov 9 + angular_velocity 3 + cov 9 + linear_acceleration 3 + cov 9
IMU_BODY = 37 * 8
IMU_VALUE = 25 * 8  # offset of linear_acceleration.x in that block
POINT_BODY = 3 * 8
POINT_VALUE = 0  # offset of point.x
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
WRENCH_BODY = 6 * 8  # wrench.force xyz, wrench.torque xyz
WRENCH_VALUE = 0  # offset of wrench.force.x
#: (fixed block size, offset of the value's x component) per message type
LAYOUT = {IMU: (IMU_BODY, IMU_VALUE), POINT_STAMPED: (POINT_BODY, POINT_VALUE),
          WRENCH_STAMPED: (WRENCH_BODY, WRENCH_VALUE)}


def header_size(frame_id: str) -> int:
    """Bytes of encapsulation + Header (padded to 8) for ``frame_id``: where the fixed block starts."""
    return 4 + -(-(12 + len(frame_id.encode()) + 1) // 8) * 8


def value_offset(msgtype: str, axis: Axis) -> int:
    """Offset of the value (``linear_acceleration``/``point``/``wrench.force`` ``.<axis>``) inside the fixed block."""
    return LAYOUT[msgtype][1] + 8 * AXES[axis]


def header(stamp_ns: np.ndarray, frame_id: str) -> np.ndarray:
    """CDR bytes of encapsulation + std_msgs/Header per stamp, padded to 8: shape (n, h)."""
    sec, nsec = np.divmod(stamp_ns, 1_000_000_000)
    if stamp_ns.size and (sec.min() < -2**31 or sec.max() >= 2**31):
        raise InputError("time stamps do not fit builtin_interfaces/Time (int32 seconds)",
                         channel=frame_id, hint="use t0_ns between 1901 and 2038")
    name = frame_id.encode() + b"\x00"
    out = np.zeros((stamp_ns.size, header_size(frame_id)), np.uint8)
    out[:, 0:4] = np.frombuffer(CDR_LE, np.uint8)
    out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(-1, 4)
    out[:, 8:12] = nsec.astype("<u4").view(np.uint8).reshape(-1, 4)
    out[:, 12:16] = np.frombuffer(np.uint32(len(name)).astype("<u4").tobytes(), np.uint8)
    out[:, 16:16 + len(name)] = np.frombuffer(name, np.uint8)
    return out


def payloads(stamp_ns: np.ndarray, values: np.ndarray, *, frame_id: str, msgtype: str, axis: Axis) -> np.ndarray:
    """Serialized messages, one row each (byte-equal to rosbags' ``serialize_cdr``).

    Imu: orientation and angular velocity flagged "not provided" (covariance[0] = -1, REP-145).
    """
    head = header(np.asarray(stamp_ns, np.int64), frame_id)
    values = np.asarray(values, np.float64)
    body = np.zeros((values.size, LAYOUT[msgtype][0] // 8), "<f8")
    if msgtype == IMU:
        body[:, 4] = -1.0  # orientation_covariance[0]
        body[:, 16] = -1.0  # angular_velocity_covariance[0]
    body[:, value_offset(msgtype, axis) // 8] = values
    return np.concatenate([head, body.view(np.uint8).reshape(values.size, body.shape[1] * 8)], axis=1)
