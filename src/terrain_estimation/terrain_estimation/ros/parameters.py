"""Parameters of the nodes: declaration with descriptions and ranges, and the helpers the vehicles share.

A vehicle states its parameters as :class:`~terrain_estimation.params.ParamSpec`
tuples (``specs_for(kind)`` of its adapter module); :func:`declare_specs`
declares them on a node with a ``ParameterDescriptor`` each (description,
range, read-only). The helpers here build the specs every vehicle has in the
same form (an input topic's frame and timeout, the divergence monitor, a
dataclass's fields) and read the validated values back.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from terrain_estimation.filters.faults import DivergenceConfig
from terrain_estimation.params import ParamSpec, ParamValue

__all__ = [
    "ESTIMATOR_NODE_SPECS",
    "declare_specs",
    "input_specs",
    "input_frame",
    "namespaced_frame",
    "divergence_specs",
    "divergence_config",
    "divergence_errors",
    "field_specs",
    "check_kind",
    "kind_specs",
    "float_value",
    "float_fields",
    "fixed_floats",
]


#: The parameters every estimator node declares besides its vehicle's (:attr:`EstimatorNode.COMMON_SPECS
#: <terrain_estimation.ros.framework.EstimatorNode.COMMON_SPECS>`).
ESTIMATOR_NODE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "qos.sensor_depth",
        200,
        "[messages] queue depth of each sensor subscription (best effort): a replay faster than the "
        "filter drops messages beyond it (ros/qos.py)",
        1,
        1_000_000,
        read_only=True,
    ),
    ParamSpec("diagnostics.period", 1.0, "[s] period of /diagnostics", 0.05, 60.0),
    ParamSpec(
        "diagnostics.stale_after",
        1.0,
        "[s] WARN when the last filter update is older than this",
        0.01,
        3600.0,
    ),
    ParamSpec(
        "diagnostics.nis_probability",
        0.95,
        "[-] two-sided probability of the chi-square band the windowed mean NIS is checked against (its sample "
        "count is the window's effective one, n / tau, tau the NIS autocorrelation time)",
        0.5,
        0.9999,
    ),
    ParamSpec(
        "diagnostics.nis_tolerance",
        0.1,
        "[-] model tolerance of the mean NIS: WARN only outside the chi-square band widened by this fraction "
        "(lower bound x (1 - tolerance), upper x (1 + tolerance)). The band alone tests white innovations of "
        "exactly the predicted variance, which no model of a real vehicle meets; a predicted innovation "
        "variance right within this fraction is consistent for a consumer of the published variances, and a "
        "sensor fault moves the mean by far more; 0: the chi-square band alone",
        0.0,
        1.0,
    ),
    ParamSpec(
        "input.take_queued",
        50,
        "[messages] after each input message the executor delivers, also take up to this many messages "
        "already queued on each input subscription and handle them in stamp order (0: one message per "
        "callback); under a backlog (a fast replay, many vehicles) this costs about half the CPU per message. "
        "Not with use_sim_time: there the inputs keep their arrival order with /clock",
        0,
        100_000,
    ),
    ParamSpec(
        "input.fast_decode",
        True,
        "decode the inputs' serialised bytes with the project's CDR decoder (ros/cdr.py: the same rclpy "
        "message objects, about 2 us instead of 9-17 us per message; anything it is unsure of goes to "
        "rclpy's deserialisation); false: rclpy's deserialize_message decodes every input",
        read_only=True,
    ),
    ParamSpec(
        "input.max_future_stamp",
        1.0,
        "[s] an input stamped further ahead of the node's clock (sim time: /clock) is rejected",
        1e-3,
        1e6,
    ),
    ParamSpec(
        "input.gravity_tolerance",
        0.7,
        "[-] an accelerometer whose mean specific force over input.gravity_window differs from gravity by "
        "more than this fraction is rejected (in g: 0.1 g; gravity removed: 0; ride vibration moves a "
        "1 s mean by up to 30 %)",
        0.01,
        0.95,
    ),
    ParamSpec(
        "input.gravity_window",
        2.0,
        "[s] window of the accelerometers' mean specific force (judged once half full; 0: no check)",
        0.0,
        60.0,
    ),
    ParamSpec(
        "input.gravity_max_tilt",
        60.0,
        "[deg] an accelerometer whose mean specific force over input.gravity_window is tilted further from +z "
        "(REP 103: z up; a vehicle at rest reads +g on z) is rejected; pointing down (z <= 0): upside down. A "
        "35 deg slope plus a sustained 0.4 g of acceleration tilts it about 57 deg; not checked without z",
        1.0,
        90.0,
    ),
    ParamSpec(
        "input.max_acceleration",
        50.0,
        "[g] an accelerometer sample with a specific-force component beyond this many standard g is a glitch "
        "(MEMS accelerometers saturate at 2-16 g; a hard wheel impact is tens of g) and is rejected alone, "
        "before it enters the gravity window",
        1.0,
        10000.0,
    ),
    ParamSpec(
        "input.restart_after_out_of_order",
        50,
        "[-] this many consecutive out-of-order samples of one topic, each later than the one before, are a "
        "source clock that went back (a bag looped without /clock): the estimator restarts on them (0: never)",
        0,
        1000000,
    ),
    ParamSpec(
        "input.log_throttle",
        5.0,
        "[s] at most one log line per rejection reason (and per silent topic) in this much wall time",
        0.0,
        3600.0,
    ),
    ParamSpec(
        "time.forward_jump",
        5.0,
        "[s] a forward jump of the node's clock (sim time: /clock) larger than this resets the estimator",
        1e-3,
        1e9,
    ),
    ParamSpec(
        "time.backward_jump",
        1e-3,
        "[s] a backward jump of the node's clock larger than this (a looping bag) resets the estimator",
        1e-9,
        1e9,
    ),
)


def input_specs(key: str, topic: str, frame: str, timeout: float, on_timeout: str) -> tuple[ParamSpec, ParamSpec]:
    """The two parameters of one input topic: its expected frame and its timeout.

    ``frames.<key>``: expected ``header.frame_id`` (see :func:`input_frame`);
    ``timeouts.<key>``: silence after which diagnostics turn WARN.
    """
    return (
        ParamSpec(
            f"frames.{key}",
            frame,
            f"expected header.frame_id of {topic}, prefixed with the namespace (a leading '/': taken as is; "
            "empty: any); a message in another frame is rejected",
        ),
        ParamSpec(
            f"timeouts.{key}",
            timeout,
            f"[s] diagnostics WARN when {topic} is silent for longer (0: never); meanwhile {on_timeout}",
            0.0,
            3600.0,
        ),
    )


def input_frame(values: Mapping[str, ParamValue], namespace: str, key: str) -> str:
    """The full expected frame of input ``key`` from ``frames.<key>`` ('' = not checked)."""
    frame = str(values[f"frames.{key}"])
    if not frame:
        return ""
    if frame.startswith("/"):
        return frame.lstrip("/")
    return namespaced_frame(namespace, frame)


def namespaced_frame(namespace: str, frame: str) -> str:
    """``frame`` prefixed with the namespace (without its slashes); the bare frame in the root namespace."""
    ns = namespace.strip("/")
    return f"{ns}/{frame}" if ns else frame


def divergence_specs(check_low_note: str | None = None) -> tuple[ParamSpec, ...]:
    """The ``filter.divergence_*`` parameters of an estimator with a divergence monitor.

    (:class:`~terrain_estimation.filters.faults.DivergenceMonitor`; read back
    by :func:`divergence_config`, reported by :func:`divergence_errors`.)

    Args:
        check_low_note: None: no ``filter.divergence_check_low`` parameter
            (the NIS band is two-sided); else that parameter, default false,
            with this note on why in its description.
    """
    specs = (
        ParamSpec(
            "filter.divergence_window",
            0,
            "[updates] divergence monitor: windowed mean NIS against its chi2 band, covariance blow-up and gate "
            "lock-out; on a divergence the filter restarts from the last good estimate (diagnostic ERROR, then OK); "
            "0 disables (default: the reproductions run without it)",
            0,
            10000,
        ),
        ParamSpec(
            "filter.divergence_probability",
            0.999,
            "[-] two-sided probability of the windowed mean NIS band of the divergence monitor",
            0.5,
            0.999999,
        ),
        ParamSpec(
            "filter.divergence_persistence",
            10,
            "[updates] consecutive out-of-band windows that make a divergence",
            1,
            10000,
        ),
    )
    if check_low_note is None:
        return specs
    return (
        *specs,
        ParamSpec(
            "filter.divergence_check_low",
            False,
            f"a windowed mean NIS below its band (covariance far too large) is a divergence too; {check_low_note}",
        ),
    )


def divergence_config(values: Mapping[str, ParamValue]) -> DivergenceConfig | None:
    """The monitor's settings from the parameters of :func:`divergence_specs`; None when disabled (window 0).

    Also reads ``filter.divergence_reinit_inflation`` and ``filter.divergence_max_variance_growth``
    where the node declares them.
    """
    window = int(values["filter.divergence_window"])
    if window <= 0:
        return None
    extra: dict[str, Any] = {}
    if "filter.divergence_check_low" in values:
        extra["check_low"] = bool(values["filter.divergence_check_low"])
    for name in ("reinit_inflation", "max_variance_growth"):
        if f"filter.divergence_{name}" in values:
            extra[name] = float(values[f"filter.divergence_{name}"])
    return DivergenceConfig(
        window=window,
        probability=float(values["filter.divergence_probability"]),
        persistence=int(values["filter.divergence_persistence"]),
        **extra,
    )


def divergence_errors(fault: str | None, divergences: int) -> list[str]:
    """:attr:`AdapterHealth.errors` of an estimator's divergence fault (empty when healthy)."""
    if not fault:
        return []
    return [f"filter diverged ({fault}): restarted from the last good estimate ({divergences} divergence(s) so far)"]


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    text = spec.description
    if spec.choices:
        text = f"{text} ({spec.range_text()})"
    desc = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.kind is float and (spec.min_value is not None or spec.max_value is not None):
        desc.floating_point_range = [
            FloatingPointRange(
                from_value=float(spec.min_value if spec.min_value is not None else -1e308),
                to_value=float(spec.max_value if spec.max_value is not None else 1e308),
                step=0.0,
            )
        ]
    elif spec.kind is int and (spec.min_value is not None or spec.max_value is not None):
        desc.integer_range = [
            IntegerRange(
                from_value=int(spec.min_value if spec.min_value is not None else -(2**62)),
                to_value=int(spec.max_value if spec.max_value is not None else 2**62),
                step=1,
            )
        ]
    return desc


def declare_specs(node: Node, specs: Sequence[ParamSpec]) -> dict[str, ParamValue]:
    """Declare ``specs`` on ``node`` and return their validated values.

    Values come from the node's overrides (``--params-file``,
    ``parameter_overrides``) or the defaults.

    Raises:
        ParameterError: an override is out of range or of the wrong type.
    """
    values: dict[str, ParamValue] = {}
    for spec in specs:
        default = spec.default
        if isinstance(default, list) and not default:
            ptype = Parameter.Type.DOUBLE_ARRAY
            param = node.declare_parameter(spec.name, ptype, _descriptor(spec))
        else:
            param = node.declare_parameter(spec.name, default, _descriptor(spec))
        value = param.value
        if value is None and isinstance(default, list) and not default:
            value = []  # rcl gives an empty list of a parameter file ("name: []") as NOT_SET
        if isinstance(value, tuple) or (hasattr(value, "tolist") and not isinstance(value, str)):
            value = list(value)
        values[spec.name] = spec.validate(value)
    return values


def field_specs(
    prefix: str,
    defaults: Any,
    fields: Sequence[tuple[str, str, str, float, float]],
    label: str = "",
    *,
    read_only: bool = True,
) -> tuple[ParamSpec, ...]:
    """``<prefix>.<field>`` specs, one per (field, unit, description, min, max); defaults of ``defaults``.

    Read-only unless ``read_only`` is False (a simulator's plant is built once; an estimator rebuilds
    its filter on a parameter change).
    """
    return tuple(
        ParamSpec(
            f"{prefix}.{name}", float(getattr(defaults, name)), f"[{unit}] {label}{text}", lo, hi, read_only=read_only
        )
        for name, unit, text, lo, hi in fields
    )


def check_kind(kind: str, expected: str, family: str) -> None:
    """ValueError unless ``kind`` is the one vehicle kind (``expected``) an adapter module serves."""
    if kind != expected:
        raise ValueError(f"unknown {family} vehicle kind {kind!r}")


def kind_specs(kind: str, expected: str, family: str, *parts: Sequence[ParamSpec]) -> tuple[ParamSpec, ...]:
    """``specs_for(kind)`` of a module serving one vehicle kind: :func:`check_kind`, then ``parts`` joined."""
    check_kind(kind, expected, family)
    return tuple(spec for part in parts for spec in part)


def float_value(values: Mapping[str, ParamValue], name: str) -> float:
    """``float(values[name])``: a validated number parameter."""
    return float(values[name])


def float_fields(
    values: Mapping[str, ParamValue], prefix: str, names: Iterable[str], *, sep: str = "."
) -> dict[str, Any]:
    """``{name: float(values["<prefix>.<name>"])}``: dataclass fields from validated parameters.

    ``sep`` joins the prefix and the field (``"_"``: parameters named ``<prefix>_<name>``).
    """
    return {name: float(values[f"{prefix}{sep}{name}"]) for name in names}


def fixed_floats(values: Mapping[str, ParamValue], name: str, size: int, what: str = "") -> tuple[float, ...]:
    """The ``size`` floats of list parameter ``name`` (``what``: what they are, named in the error).

    Raises:
        ValueError: the list does not hold ``size`` values.
    """
    v = tuple(float(x) for x in values[name])
    if len(v) != size:
        held = f" ({what})" if what else ""
        raise ValueError(f"{name} must hold {size} values{held}, got {len(v)}: {list(v)}")
    return v
