"""terrain_msgs is a real interface package: every type goes through live
rclpy pub/sub and through a rosbag2 file that a plain rosbags reader decodes
from the definitions the bag carries."""

from __future__ import annotations

import array
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.bag import AtomicBagWriter, terrain_msgs_definitions, typestore
from terrain_msgs.msg import (
    SkidSteerState,
    SoilStiffness,
    TerrainResponseModel,
    WheelTerrain,
    WheelTerrainArray,
)


def _stamp(msg, sec=12, nanosec=345):
    msg.header.stamp.sec = sec
    msg.header.stamp.nanosec = nanosec
    msg.header.frame_id = "quarter_car/base_link"
    return msg


def terrain_samples():
    soil = _stamp(
        SoilStiffness(
            k_s=651.1e3,
            k_s_variance=4e6,
            k_tot=137.93e3,
            k_tot_variance=1e4,
            terrain_class="graneville_loam",
            class_confidence=0.93,
            converged=True,
            soil_change_detected=False,
            nis=1.7,
        )
    )
    skid = _stamp(
        SkidSteerState(
            vx=8.3,
            vy=-0.12,
            yaw_rate=0.2,
            body_sideslip=-0.0144,
            slip_left=0.03,
            slip_right=-0.02,
            tire_sideslip=[0.01, 0.02, 0.03, -0.01, -0.02, -0.03],
            icr_x=1.2,
            icr_y=41.5,
            icr_valid=True,
            fading_factor=1.4,
            noise_scale=0.8,
        )
    )
    wheels = _stamp(
        WheelTerrainArray(
            wheels=[
                WheelTerrain(
                    wheel=name,
                    slip=0.1 * i,
                    normal_load=40.0 + i,
                    drawbar_pull=3.0 - i,
                    resistive_torque=0.4 * i,
                    contact_angle=0.3,
                )
                for i, name in enumerate(["front", "middle", "rear"])
            ]
        )
    )
    model = _stamp(
        TerrainResponseModel(
            order=2,
            dp_coefficients=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            tau_coefficients=[0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
            slip_min=0.0,
            slip_max=0.6,
            load_min=20.0,
            load_max=80.0,
            samples=42,
            dp_rms=0.7,
            tau_rms=0.05,
            dp_covariance=[0.01 * (k + 1) for k in range(36)],
            tau_covariance=[1e-4 * (k + 1) for k in range(36)],
            dp_holdout_rms=0.9,
            tau_holdout_rms=0.06,
            dp_estimate_rms=0.4,
            tau_estimate_rms=0.02,
            dp_prediction_rms=1.1,
            tau_prediction_rms=0.08,
            validation_samples=42,
        )
    )
    return [soil, skid, wheels, model]


def contract_samples():
    imu = _stamp(Imu())
    imu.linear_acceleration.z = 9.80665
    imu.orientation_covariance[0] = -1.0
    joints = _stamp(
        JointState(name=["left_motor", "right_motor"], position=[1.0, 2.0], velocity=[3.0, 4.0], effort=[0.5, 0.6])
    )
    profile = _stamp(PointStamped())
    profile.point.x, profile.point.z = 12.5, -0.004
    odom = _stamp(Odometry(child_frame_id="skid_steer/base_link"))
    odom.twist.twist.linear.x = 8.0
    twist = _stamp(TwistStamped())
    twist.twist.linear.x = 0.02
    wrench = _stamp(WrenchStamped())
    wrench.wrench.force.z = 55.0
    clock = Clock()
    clock.clock.sec = 3
    diagnostics = _stamp(
        DiagnosticArray(
            status=[DiagnosticStatus(level=DiagnosticStatus.WARN, name="x", values=[KeyValue(key="k", value="v")])]
        )
    )
    return [imu, joints, profile, odom, twist, wrench, clock, diagnostics] + terrain_samples()


def _equal(a, b) -> bool:
    """Field-wise equality of an rclpy message and a rosbags-decoded one."""
    if hasattr(a, "get_fields_and_field_types"):
        return all(_equal(getattr(a, f), getattr(b, f)) for f in a.get_fields_and_field_types())
    if isinstance(a, (list, tuple, array.array)) or getattr(a, "ndim", 0) > 0:
        a_list, b_list = list(a), list(b)
        return len(a_list) == len(b_list) and all(_equal(x, y) for x, y in zip(a_list, b_list, strict=True))
    if isinstance(a, float):
        return float(a) == float(b)  # CDR keeps float64 bits exactly
    if isinstance(a, bytes):
        return a == (b if isinstance(b, bytes) else bytes([b]))
    return a == b


def test_every_terrain_msg_type_has_a_definition():
    defined = set(terrain_msgs_definitions())
    assert defined == {f"terrain_msgs/msg/{type(m).__name__}" for m in terrain_samples()} | {
        "terrain_msgs/msg/WheelTerrain"
    }
    store = typestore()
    for name in defined:
        assert name in store.fielddefs


def test_live_pubsub_every_terrain_msg_type(rclpy_context):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from terrain_estimation.ros.qos import ESTIMATE_QOS

    node = Node("msg_roundtrip", context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    received: dict[str, list] = {}
    pubs = {}
    samples = terrain_samples()
    for msg in samples:
        name = type(msg).__name__
        topic = f"roundtrip/{name}"
        node.create_subscription(type(msg), topic, lambda m, n=name: received.setdefault(n, []).append(m), ESTIMATE_QOS)
        pubs[name] = node.create_publisher(type(msg), topic, ESTIMATE_QOS)
    for _ in range(200):  # discovery takes a moment; publish until every type arrived
        for msg in samples:
            if type(msg).__name__ not in received:
                pubs[type(msg).__name__].publish(msg)
        executor.spin_once(timeout_sec=0.05)
        if len(received) == len(samples):
            break
    node.destroy_node()
    executor.shutdown()
    assert set(received) == {type(m).__name__ for m in samples}
    for msg in samples:
        assert received[type(msg).__name__][0] == msg
    assert rclpy.ok(context=rclpy_context)


def test_bag_roundtrip_every_contract_type_decodes_without_project_code(tmp_path: Path):
    from rosbags.highlevel import AnyReader

    samples = contract_samples()
    bag = tmp_path / "contract"
    with AtomicBagWriter(bag) as writer:
        for i, msg in enumerate(samples):
            writer.write(f"/vehicle/{type(msg).__name__}", msg, 1_000 + i)
    # A reader with no project code: AnyReader builds its types from the
    # message definitions stored in the bag.
    with AnyReader([bag]) as reader:
        decoded = {c.topic.split("/")[-1]: reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()}
    assert set(decoded) == {type(m).__name__ for m in samples}
    for msg in samples:
        assert _equal(msg, decoded[type(msg).__name__]), type(msg).__name__


def test_atomic_writer_leaves_previous_bag_on_error(tmp_path: Path):
    from terrain_estimation.bag import read_bag

    bag = tmp_path / "out"
    first = terrain_samples()[0]
    with AtomicBagWriter(bag) as writer:
        writer.write("/a", first, 1)
    with pytest.raises(RuntimeError, match="crash while writing"):
        with AtomicBagWriter(bag, overwrite=True) as writer:
            writer.write("/a", first, 2)
            raise RuntimeError("crash while writing")
    assert [m.log_time_ns for m in read_bag(bag)] == [1]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
