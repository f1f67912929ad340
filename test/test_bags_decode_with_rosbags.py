"""Every bag the project writes decodes without project code (issue 19), and read_bag's input checks.

rclpy's ``serialize_message`` returns buffers longer than their CDR for
messages with an empty sequence (``JointState.effort``), which rosbags'
``AnyReader`` refuses ("CDR message size mismatch"). Every topic of every
shipped bag, and of bags freshly written by ``terrain-simulate`` (each
vehicle), by the estimator (``estimate_bag`` + the writer) and by the
BorealTC importer, must decode message by message both with ``AnyReader``
(from the definitions stored in the bag) and with rclpy.

``read_bag`` refuses a topic of another type before reading any message,
skips (and reports) a message whose bytes do not decode, and still fails on
corrupt storage.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from terrain_estimation.bag import (
    AtomicBagWriter,
    BagError,
    MissingTopicsError,
    TopicTypeError,
    UndecodableMessagesWarning,
    bag_contents,
    message_class,
    read_bag,
    require_topics,
    typestore,
)

BAGS = Path(__file__).resolve().parents[1] / "bags"
SHIPPED = sorted(p for p in BAGS.iterdir() if (p / "metadata.yaml").is_file())


def _assert_decodes(bag: Path) -> int:
    """Decode every message of ``bag`` with AnyReader and with rclpy, check its bytes are canonical; return the count.

    Canonical: what rosbags' serialiser writes for the decoded values (padding zeroed), so that the bytes are a
    function of the values: no process memory in a bag, the same bag from the same seed.
    """
    from rclpy.serialization import deserialize_message
    from rosbags.highlevel import AnyReader

    count = 0
    expected = {t.topic: t.count for t in bag_contents(bag).values()}
    seen: dict[str, int] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise AssertionError(f"{bag.name} {conn.topic}: rosbags: {exc}") from exc
            canonical = bytes(reader.typestore.serialize_cdr(msg, conn.msgtype))
            assert bytes(raw) == canonical, f"{bag.name} {conn.topic}: bytes beyond the values (uninitialised padding?)"
            deserialize_message(bytes(raw), message_class(conn.msgtype))
            seen[conn.topic] = seen.get(conn.topic, 0) + 1
            count += 1
    assert seen == expected and count > 0
    return count


def test_shipped_bags_decode_with_rosbags_and_rclpy() -> None:
    assert {p.name for p in SHIPPED} >= {"quarter_car_graneville_iso_d_10ms", "lrv_regolith_iso_g_2ms"}
    for bag in SHIPPED:
        _assert_decodes(bag)


@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv", "skid_steer", "rover"])
def test_simulated_and_estimated_bags_decode(tmp_path: Path, vehicle: str) -> None:
    from terrain_estimation.tools.estimate import estimate_bag
    from vehicle_sim.tools.simulate import record

    sim = tmp_path / "sim"
    record(vehicle, 1.0, sim)
    _assert_decodes(sim)
    run = estimate_bag(sim, vehicle)
    est = tmp_path / "estimates"
    with AtomicBagWriter(est, inputs=[sim]) as writer:
        writer.write_all(run.outputs)
    _assert_decodes(est)


def test_borealtc_import_decodes(tmp_path: Path) -> None:
    from vehicle_sim.tools.borealtc import main

    folder = tmp_path / "data" / "GRAVEL"
    folder.mkdir(parents=True)
    (folder / "imu_03.csv").write_text(
        "time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 100},0,0,0.1,0,0,9.8\n" for k in range(50))
    )
    (folder / "pro_03.csv").write_text(
        "time,curL,curR,velL,velR\n" + "".join(f"{k / 6.5},1,2,0.2,0.3\n" for k in range(4))
    )
    assert main(["--data", str(tmp_path / "data"), "--out", str(tmp_path / "out")]) == 0
    assert _assert_decodes(tmp_path / "out" / "GRAVEL" / "run_03") == 54


def _raw_bag(path: Path, messages: list[tuple[str, str, bytes]]) -> Path:
    """A bag written by rosbags' Writer (MCAP, version 9) from raw CDR bytes, log times 1, 2, ..."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns: dict[str, object] = {}
        for i, (topic, msgtype, raw) in enumerate(messages, start=1):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], i, raw)  # type: ignore[arg-type]
    return path


def _cdr(msgtype: str, **fields: object) -> bytes:
    store = typestore()
    cls = store.types[msgtype]
    if msgtype == "geometry_msgs/msg/Vector3Stamped":
        header = store.types["std_msgs/msg/Header"](store.types["builtin_interfaces/msg/Time"](0, 0), "f")
        msg = cls(header, store.types["geometry_msgs/msg/Vector3"](1.0, 2.0, 3.0))
    else:
        msg = cls(**fields)
    return bytes(store.serialize_cdr(msg, msgtype))


def test_topic_of_another_type_is_refused_before_reading(tmp_path: Path) -> None:
    bag = _raw_bag(
        tmp_path / "wrong",
        [
            ("/std/x", "std_msgs/msg/Float64", _cdr("std_msgs/msg/Float64", data=1.0)),
            ("/quarter_car/imu/body", "geometry_msgs/msg/Vector3Stamped", _cdr("geometry_msgs/msg/Vector3Stamped")),
        ],
    )
    messages = read_bag(bag, types={"/std/x": "std_msgs/msg/Float64", "/quarter_car/imu/body": "sensor_msgs/msg/Imu"})
    with pytest.raises(
        TopicTypeError, match=r"/quarter_car/imu/body.*geometry_msgs/msg/Vector3Stamped.*sensor_msgs/msg/Imu"
    ):
        next(messages)  # the first message (of the right type) is not yielded either
    assert [m.msg.data for m in read_bag(bag, ["/std/x"], types={"/std/x": "std_msgs/msg/Float64"})] == [1.0]
    with pytest.raises(MissingTopicsError, match=r"no messages on /q/joint_states.*found /quarter_car/imu/body"):
        require_topics(bag, {"/std/x": "std_msgs/msg/Float64", "/q/joint_states": "sensor_msgs/msg/JointState"})
    with pytest.raises(TopicTypeError):
        require_topics(bag, {"/quarter_car/imu/body": "sensor_msgs/msg/Imu"})


def test_undecodable_message_is_skipped_and_reported(tmp_path: Path) -> None:
    good = [_cdr("std_msgs/msg/Float64", data=float(i)) for i in range(4)]
    garbage = b"\x00\x01\x00\x00\xff\xff"  # a CDR header and 2 bytes where 8 are needed
    bag = _raw_bag(tmp_path / "bag", [("/x", "std_msgs/msg/Float64", raw) for raw in (*good[:2], garbage, *good[2:])])
    rejected: list[tuple[str, int, Exception]] = []
    values = [m.msg.data for m in read_bag(bag, on_undecodable=lambda *args: rejected.append(args))]
    assert values == [0.0, 1.0, 2.0, 3.0]
    assert [(topic, t) for topic, t, _ in rejected] == [("/x", 3)] and isinstance(rejected[0][2], Exception)
    with pytest.warns(UndecodableMessagesWarning, match=r"skipped 1 message.*/x 1"):
        assert len(list(read_bag(bag))) == 4


def test_corrupt_storage_still_raises_with_a_callback(tmp_path: Path) -> None:
    bag = shutil.copytree(BAGS / "quarter_car_graneville_iso_d_10ms", tmp_path / "cut")
    (mcap,) = bag.glob("*.mcap")
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    rejected: list[object] = []
    with pytest.raises(BagError, match=r"cut.*unreadable after \d+ messages"):
        for _ in read_bag(bag, on_undecodable=lambda *args: rejected.append(args)):
            pass
