"""The effect signature of a withheld bag: its numeric channels recorded per topic and scored against the noise σ.

Labels only (the diagnosis never sees it); the twin runs and the noise σ
come from :mod:`vehicle_sim.tools.withheld`.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vehicle_sim.independent.blind_suite import g4

__all__ = ["RESPONSE_TOPICS", "Series", "signature"]

_NUMERIC_TYPES = frozenset(
    {"double", "float", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}
)
_QUATERNION_TYPE = "geometry_msgs/Quaternion"


@dataclass(frozen=True)
class _Field:
    path: str
    kind: str  # "scalar" | "array" | "quaternion"
    get: Callable[[Any], Any]


_LAYOUTS: dict[type, tuple[_Field, ...]] = {}


def _layout(msg_type: type) -> tuple[_Field, ...]:
    """The numeric leaves of a message type: scalars, numeric arrays/sequences and quaternions.

    Generic over rosidl message types: left out are the header, strings,
    booleans, ``*covariance`` arrays (metadata, not readings) and arrays of
    messages.
    """
    fields: list[_Field] = []

    def walk(cls: type, prefix: str) -> None:
        instance = cls()
        for name, typ in cls.get_fields_and_field_types().items():  # type: ignore[attr-defined]
            path = f"{prefix}{name}"
            if name == "header" or name.endswith("covariance"):
                continue
            is_array = typ.startswith("sequence<") or typ.endswith("]")
            base = typ[len("sequence<") :].split(",")[0].rstrip(">") if typ.startswith("sequence<") else typ
            base = base.split("[")[0].strip()
            if base in _NUMERIC_TYPES:
                fields.append(_Field(path, "array" if is_array else "scalar", operator.attrgetter(path)))
            elif "/" in base and not is_array:
                if base == _QUATERNION_TYPE:
                    fields.append(_Field(path, "quaternion", operator.attrgetter(path)))
                else:
                    walk(type(getattr(instance, name)), f"{path}.")

    cached = _LAYOUTS.get(msg_type)
    if cached is None:
        walk(msg_type, "")
        cached = _LAYOUTS[msg_type] = tuple(fields)
    return cached


Series = tuple[np.ndarray, list[str], np.ndarray, list[str], np.ndarray]
"""One topic of a recorded run: stamps (ns), channel names, values (N, C), quaternion names, quaternions (N, Q, 4)."""


class _Recorder:
    """Collects the numeric channels of a run's sensor messages, per topic."""

    def __init__(self) -> None:
        self._stamps: dict[str, list[int]] = {}
        self._names: dict[str, tuple[list[str], list[str]]] = {}
        self._rows: dict[str, list[list[float]]] = {}
        self._quats: dict[str, list[list[float]]] = {}

    def add(self, topic: str, stamp_ns: int, msg: Any) -> None:
        layout = _layout(type(msg))
        row: list[float] = []
        quat: list[float] = []
        if topic not in self._names:
            names: list[str] = []
            quat_names: list[str] = []
            labels = list(getattr(msg, "name", [])) if hasattr(msg, "name") else []
            for f in layout:
                if f.kind == "scalar":
                    names.append(f"{topic} {f.path}")
                elif f.kind == "array":
                    n = len(f.get(msg))
                    tags = labels if len(labels) == n and all(isinstance(x, str) for x in labels) else range(n)
                    names += [f"{topic} {f.path}[{tag}]" for tag in tags]
                else:
                    quat_names.append(f"{topic} {f.path}")
            self._names[topic] = (names, quat_names)
            self._stamps[topic], self._rows[topic], self._quats[topic] = [], [], []
        for f in layout:
            value = f.get(msg)
            if f.kind == "scalar":
                row.append(float(value))
            elif f.kind == "array":
                row.extend(float(v) for v in value)
            else:
                quat += (float(value.x), float(value.y), float(value.z), float(value.w))
        if len(row) != len(self._names[topic][0]):
            raise ValueError(f"{topic}: the message layout changed during the run ({len(row)} values)")
        self._stamps[topic].append(stamp_ns)
        self._rows[topic].append(row)
        self._quats[topic].append(quat)

    def series(self) -> dict[str, Series]:
        """topic → (stamps, scalar channel names, values (N, C), quaternion names, quaternions (N, Q, 4))."""
        out: dict[str, Series] = {}
        for topic, stamps in self._stamps.items():
            names, quat_names = self._names[topic]
            n = len(stamps)
            values = np.asarray(self._rows[topic], dtype=float).reshape(n, len(names))
            quats = np.asarray(self._quats[topic], dtype=float).reshape(n, len(quat_names), 4)
            out[topic] = (np.asarray(stamps, dtype=np.int64), names, values, quat_names, quats)
        return out


#: Per vehicle, the topics whose channels count in the signature's ``snr``: the vehicle's
#: *responses*. Left out are the inputs every replay of the vehicle is driven by (the
#: measured road profile; the drive's commands and encoders in joint_states) and the GNSS
#: fix (an integral of the motion: its drift from an unknown start is no evidence a blind
#: diagnosis can use). Their channels are still listed, with ``in_snr`` false.
RESPONSE_TOPICS: Mapping[str, tuple[str, ...]] = {
    "quarter_car": ("imu/body", "imu/wheel"),
    "lrv": ("imu/body",),
    "skid_steer": ("imu",),
    "rover": ("imu", "velocimeter", "wheel/front/load", "wheel/middle/load", "wheel/rear/load"),
}


def _topic_of(channel: str) -> str:
    return channel.split(" ", 1)[0]


def signature(
    deltas: Mapping[str, np.ndarray], sigma: Mapping[str, float], response: Sequence[str] | None = None
) -> dict[str, Any]:
    """The effect signature of the differences ``deltas`` (effect − twin) given the noise σ per channel.

    Returns ``snr`` = sqrt(Σ_channels Σ_samples (Δ/σ)²) over the noisy
    channels (σ > 0) of the ``response`` topics (default: every topic; see
    :data:`RESPONSE_TOPICS`), ``snr_all`` over every noisy channel, per noisy
    channel ``rms_over_sigma`` = RMS(Δ)/σ, its own ``snr`` (its share) and
    ``in_snr``, ``most_affected`` (the response channel of the largest share;
    None when none changed), ``samples`` compared, and ``noise_free_changed``:
    max |Δ| of the noise-free channels (σ = 0) that changed, which are left
    out of the SNR (no noise scale to measure them against).
    """
    total = 0.0
    total_all = 0.0
    samples = 0
    channels: dict[str, dict[str, float]] = {}
    noise_free: dict[str, float] = {}
    for name, d in deltas.items():
        s = sigma.get(name)
        if s is None:
            raise ValueError(f"no noise sigma for channel {name!r}")
        if not s > 0.0:
            if d.size and np.any(d != 0.0):
                noise_free[name] = g4(float(np.max(np.abs(d))))
            continue
        z2 = float(np.sum((d / s) ** 2))
        counted = response is None or _topic_of(name) in response
        total_all += z2
        if counted:
            total += z2
            samples += d.size
        channels[name] = {
            "rms_over_sigma": g4(math.sqrt(z2 / d.size)) if d.size else 0.0,
            "snr": g4(math.sqrt(z2)),
            "in_snr": counted,
        }
    counted_names = [c for c in channels if channels[c]["in_snr"]]
    most = max(counted_names, key=lambda c: channels[c]["snr"]) if total > 0.0 else None
    return {
        "snr": g4(math.sqrt(total)),
        "snr_all": g4(math.sqrt(total_all)),
        "most_affected": most,
        "samples": samples,
        "channels": channels,
        "noise_free_changed": noise_free,
    }
