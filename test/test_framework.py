"""The node framework: parameters with descriptions and ranges, rejection of
invalid updates, diagnostics, simulated time driven by a simulator node."""

from __future__ import annotations

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from terrain_estimation.params import ParameterError, ParamSpec, load_parameter_file, resolve_parameters
from terrain_estimation.ros.framework import AdapterHealth, EstimatorNode, SimulatorNode, TopicSpec
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_sec

SPECS = (
    ParamSpec("gain", 0.5, "[-] smoothing gain of the test estimator", 0.0, 1.0),
    ParamSpec("mode", "mean", "estimation mode", choices=("mean", "last")),
)


class RunningMeanAdapter:
    """A test double: exponential smoothing of PointStamped.point.z."""

    def __init__(self, values, namespace):
        self.gain = float(values["gain"])
        self.inputs = [TopicSpec("value", "value", PointStamped, "sensor")]
        self.outputs = [TopicSpec("mean", "mean", PointStamped, "estimate")]
        self.health = AdapterHealth(nis_dof=1)
        self.mean = None

    def handle(self, key, msg):
        z = msg.point.z
        self.mean = z if self.mean is None else (1 - self.gain) * self.mean + self.gain * z
        self.health.updates += 1
        self.health.last_update_time = stamp_to_sec(msg.header.stamp)
        self.health.nis.append(1.0)
        out = PointStamped(header=msg.header)
        out.point.z = self.mean
        return [("mean", out)]

    def reset(self):
        self.mean = None


class CounterSimAdapter:
    period = 0.01

    def __init__(self, values, namespace):
        self.outputs = [TopicSpec("value", "value", PointStamped, "sensor")]
        self.t = 0.0

    def step(self):
        self.t = round(self.t + self.period, 9)
        msg = PointStamped()
        msg.header.stamp = sec_to_stamp(self.t)
        msg.point.z = self.t
        return self.t, [("value", msg)]


def test_paramspec_validation():
    spec = ParamSpec("k", 1.0, "[N/m] stiffness", 0.0, 10.0)
    assert spec.validate(3) == 3.0
    with pytest.raises(ParameterError, match="outside"):
        spec.validate(11.0)
    with pytest.raises(ParameterError, match="not finite"):
        spec.validate(float("nan"))
    with pytest.raises(ParameterError, match="expected a number"):
        spec.validate("3")
    choice = ParamSpec("f", "sckf", "filter", choices=("sckf", "ekf"))
    with pytest.raises(ParameterError, match="one of sckf, ekf"):
        choice.validate("kf")


def test_parameter_file_sections(tmp_path):
    path = tmp_path / "v.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    gain: 0.2\n    vehicle:\n      mass: 3.0\n"
        "estimator:\n  ros__parameters:\n    gain: 0.3\n"
        "other:\n  ros__parameters:\n    gain: 0.9\n"
    )
    values = load_parameter_file(path, ["estimator"])
    assert values == {"gain": 0.3, "vehicle.mass": 3.0}
    assert resolve_parameters(SPECS, values)["gain"] == 0.3
    with pytest.raises(ParameterError, match="unknown parameter"):
        resolve_parameters(SPECS, values, strict=True)


def test_estimator_node_parameters_and_diagnostics(rclpy_context):
    node = EstimatorNode(
        "mean_estimator",
        SPECS,
        RunningMeanAdapter,
        namespace="/veh",
        parameter_overrides=[Parameter("gain", value=0.25)],
        context=rclpy_context,
    )
    try:
        described = node.describe_parameter("gain")
        assert "smoothing gain" in described.description
        assert described.floating_point_range[0].to_value == 1.0
        assert node.values["gain"] == 0.25
        result = node.set_parameters([Parameter("gain", value=2.0)])[0]
        assert not result.successful and "out of range" in result.reason
        result = node.set_parameters([Parameter("mode", value="median")])[0]
        assert not result.successful and "one of mean, last" in result.reason
        assert node.adapter.gain == 0.25
        assert node.set_parameters([Parameter("gain", value=0.75)])[0].successful
        assert node.adapter.gain == 0.75  # rebuilt with the new value
        status = node.diagnostic_status()
        assert status.level == DiagnosticStatus.WARN and "no filter update" in status.message
        assert isinstance(status.level, bytes)
    finally:
        node.destroy_node()


def test_out_of_range_override_is_refused(rclpy_context):
    with pytest.raises(Exception, match="gain"):
        EstimatorNode(
            "bad", SPECS, RunningMeanAdapter, parameter_overrides=[Parameter("gain", value=5.0)], context=rclpy_context
        )


def test_simulator_drives_sim_time_and_estimator(rclpy_context):
    sim = SimulatorNode(
        "sim",
        (),
        CounterSimAdapter,
        namespace="/veh",
        context=rclpy_context,
        parameter_overrides=[Parameter("realtime_factor", value=0.0), Parameter("duration", value=0.5)],
    )
    est = EstimatorNode(
        "est",
        SPECS,
        RunningMeanAdapter,
        namespace="/veh",
        context=rclpy_context,
        parameter_overrides=[Parameter("use_sim_time", value=True), Parameter("diagnostics.period", value=0.1)],
    )
    diagnostics: list[DiagnosticArray] = []
    est.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(sim)
    executor.add_node(est)
    try:
        for _ in range(20000):
            executor.spin_once(timeout_sec=0.01)
            if sim.done and est.messages_handled > 0 and diagnostics and est.adapter.health.updates >= 40:
                break
        assert sim.done and sim.sim_time == pytest.approx(0.5)
        # Best effort over loopback: the estimator saw (nearly) every step.
        assert est.adapter.health.updates >= 40
        # The estimator's clock follows /clock, not the wall clock.
        assert est.get_clock().now().nanoseconds * 1e-9 == pytest.approx(0.5, abs=0.05)
        assert diagnostics and diagnostics[-1].status[0].level in (DiagnosticStatus.OK, DiagnosticStatus.WARN)
    finally:
        executor.shutdown()
        sim.destroy_node()
        est.destroy_node()


class TwoTopicRecorder:
    """A test double with two inputs that records the order in which messages reach it."""

    def __init__(self, values, namespace):
        self.inputs = [
            TopicSpec("fast", "fast", PointStamped, "sensor"),
            TopicSpec("slow", "slow", PointStamped, "sensor"),
        ]
        self.outputs = [TopicSpec("mean", "mean", PointStamped, "estimate")]
        self.health = AdapterHealth(nis_dof=1)
        self.seen: list[tuple[str, float]] = []

    def handle(self, key, msg):
        self.seen.append((key, stamp_to_sec(msg.header.stamp)))
        return []

    def reset(self):
        pass


def _executor(kind, context):
    """What spin_node runs (``"events"``) or rclpy's wait-based executor (``"single"``)."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def _two_topic_publishers(source):
    """Publishers of TwoTopicRecorder's topics, once its subscriptions are discovered."""
    import time

    from terrain_estimation.ros.qos import SENSOR_QOS

    pubs = {k: source.create_publisher(PointStamped, k, SENSOR_QOS) for k in ("fast", "slow")}
    deadline = time.monotonic() + 10.0
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        assert time.monotonic() < deadline, "the recorder's subscriptions were not discovered"
        time.sleep(0.02)
    return pubs


@pytest.mark.parametrize("executor_kind", ["single", "events"])
@pytest.mark.parametrize(
    ("take_queued", "sim_time", "fast_decode"),
    [(0, False, True), (50, False, True), (5, False, True), (50, True, True), (50, False, False)],
)
def test_queued_inputs_are_taken_in_stamp_order_and_none_is_lost(
    rclpy_context, take_queued, sim_time, fast_decode, executor_kind
):
    """A burst queued on two topics reaches the adapter whole; with input.take_queued the first
    callback takes the rest, merged by stamp (each topic in its own order), and a take smaller
    than the burst holds back what a later message of the cut topic could precede; with 0, or
    under sim time (inputs keep their order with /clock), one message per executor callback.
    The same with rclpy decoding the inputs (input.fast_decode false) instead of ros/cdr.py."""
    import time

    from terrain_estimation.ros.cdr import decoder_for

    node = EstimatorNode(
        "recorder",
        (),
        TwoTopicRecorder,
        namespace="/veh",
        parameter_overrides=[
            Parameter("input.take_queued", value=take_queued),
            Parameter("use_sim_time", value=sim_time),
            Parameter("input.fast_decode", value=fast_decode),
        ],
        context=rclpy_context,
    )
    decoders = [decode for _, _, decode in node._input_subscriptions]
    assert all((d is decoder_for(PointStamped)) == fast_decode for d in decoders)
    source = rclpy.create_node("source", namespace="/veh", context=rclpy_context)
    executor = _executor(executor_kind, rclpy_context)
    executor.add_node(node)
    try:
        pubs = _two_topic_publishers(source)
        # The slow topic first (as a driver whose messages arrive late), then the fast one.
        # 30 fast messages: a take of 5 empties the queue exactly, so the last slow one (after
        # them) is held with nothing left queued to wake the node: the guard condition must.
        sent = {"slow": [0.005, 0.015, 0.025, 0.035], "fast": [0.001 * i for i in range(1, 31)]}
        for key in ("slow", "fast"):
            for t in sent[key]:
                msg = PointStamped()
                msg.header.stamp = sec_to_stamp(t)
                pubs[key].publish(msg)
        time.sleep(0.5)  # every message queued on the subscriptions
        executor.spin_once(timeout_sec=1.0)
        first_callback = len(node.adapter.seen)
        deadline = time.monotonic() + 10.0
        while node.messages_handled < 34 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        seen = node.adapter.seen
        assert node.messages_handled == len(seen) == 34
        for key in ("slow", "fast"):
            assert [t for k, t in seen if k == key] == pytest.approx(sent[key])
        stamps = [t for _, t in seen]
        if take_queued and not sim_time:
            assert stamps == sorted(stamps), "merged by stamp"
            if take_queued >= 30:
                assert first_callback == 34, "the first callback took every queued message"
            else:
                assert 1 < first_callback < 34, "the cut topic's later messages waited for the next call"
        else:  # arrival order: the slow topic's burst first
            assert stamps != sorted(stamps)
            if executor_kind == "single":  # (the events executor runs a topic's ready messages at once)
                assert first_callback == 1
    finally:
        executor.shutdown()
        source.destroy_node()
        node.destroy_node()


@pytest.mark.parametrize(("fast_decode", "take_queued"), [(True, 50), (False, 50), (True, 1)])
@pytest.mark.parametrize("executor_kind", ["single", "events"])
def test_bytes_that_do_not_decode_are_rejected_and_the_node_goes_on(
    rclpy_context, fast_decode, take_queued, executor_kind
):
    """A sample whose bytes are not its topic's type (a corrupt or mistyped publisher) is rejected
    with a log line and counted; the node keeps running and handles the next messages. rclpy's
    own take would raise in the executor on such bytes and stop the node. With a take of 1 the
    corrupt sample is the whole take of its topic (nothing of it to bound the merge by)."""
    import time

    node = EstimatorNode(
        "recorder",
        (),
        TwoTopicRecorder,
        namespace="/veh",
        parameter_overrides=[
            Parameter("input.fast_decode", value=fast_decode),
            Parameter("input.take_queued", value=take_queued),
        ],
        context=rclpy_context,
    )
    source = rclpy.create_node("source", namespace="/veh", context=rclpy_context)
    executor = _executor(executor_kind, rclpy_context)
    executor.add_node(node)
    try:
        pubs = _two_topic_publishers(source)
        good = PointStamped()
        good.header.stamp = sec_to_stamp(1.0)
        pubs["slow"].publish(good)  # delivered first: its callback takes from "fast"
        pubs["fast"].publish(b"\x00\x01\x00\x00\xff")  # serialised bytes, cut short: not a PointStamped
        good.header.stamp = sec_to_stamp(2.0)
        pubs["fast"].publish(good)
        time.sleep(0.3)  # all three queued
        deadline = time.monotonic() + 10.0
        while node.messages_handled < 3 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert node.messages_handled == 3
        assert node.adapter.seen == [("slow", 1.0), ("fast", 2.0)]
        assert node.guard.rejected == {"fast: (serialised message) does not decode as PointStamped": 1}
    finally:
        executor.shutdown()
        source.destroy_node()
        node.destroy_node()


def _nis_message(rclpy_context, values) -> str:
    node = EstimatorNode("nis_estimator", SPECS, RunningMeanAdapter, namespace="/nis", context=rclpy_context)
    try:
        node.adapter.health.nis.extend(values)
        return node.diagnostic_status().message
    finally:
        node.destroy_node()


def test_nis_band_allows_the_model_tolerance_and_no_more(rclpy_context):
    """White innovations whose variance is 7 % below the prediction over a full window: outside the chi-square
    band (its width is about 1/sqrt(n dof)), inside the default model tolerance of 10 %; 25 % low WARNs."""
    import numpy as np

    rng = np.random.default_rng(3)
    white = rng.chisquare(11, 200)  # the health window holds 200
    white = white / white.mean()  # mean NIS exactly the dof after the scaling below
    node = EstimatorNode("nis_tolerance", SPECS, RunningMeanAdapter, namespace="/nis", context=rclpy_context)
    try:
        node.adapter.health.nis_dof = 11
        node.adapter.health.nis.extend(0.93 * 11 * white)
        assert "innovations inconsistent" not in node.diagnostic_status().message
        node.values["diagnostics.nis_tolerance"] = 0.0
        assert "innovations inconsistent" in node.diagnostic_status().message
        node.values["diagnostics.nis_tolerance"] = 0.1
        node.adapter.health.nis.clear()
        node.adapter.health.nis.extend(0.75 * 11 * white)
        assert "innovations inconsistent" in node.diagnostic_status().message
    finally:
        node.destroy_node()


def test_nis_band_counts_the_effective_samples_of_coloured_innovations(rclpy_context):
    """Innovations coloured by model error (AR(1), rho 0.95) with a mean NIS 30 % low: healthy, not WARN;
    the same mean from white innovations is a real inconsistency (WARN); a fault (5x) WARNs either way."""
    import numpy as np

    rng = np.random.default_rng(0)
    z = np.zeros(200)
    for k in range(1, 200):
        z[k] = 0.95 * z[k - 1] + np.sqrt(1 - 0.95**2) * rng.standard_normal()
    coloured = 0.7 * z**2 / np.mean(z**2)
    white = rng.standard_normal(200) ** 2
    white = 0.7 * white / white.mean()
    assert "innovations inconsistent" not in _nis_message(rclpy_context, coloured)
    assert "innovations inconsistent" in _nis_message(rclpy_context, white)
    assert "innovations inconsistent" in _nis_message(rclpy_context, 5.0 * coloured)
