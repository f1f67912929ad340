"""``terrain-simulate --vehicle V --duration T -o BAG``: record a simulated bag.

Steps the same simulator adapter the ``quarter_car_sim`` node runs and writes
exactly the messages the node would publish (plus ``/clock``) into a rosbag2
bag, with no ROS graph: a bag of seconds of driving takes a fraction of that.
The log time of each message is its header stamp (``/clock``: the step time).

An existing output is refused (exit 2) unless ``--overwrite`` is given, and
even then only a previous bag is replaced, never a directory of other files
or one of the run's inputs (the ``--config`` file); see
:mod:`terrain_estimation.outputs`.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rosgraph_msgs.msg import Clock

from terrain_estimation.bag import AtomicBagWriter
from terrain_estimation.cli import EXIT_OK, run_cli
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
from terrain_estimation.tools.estimate import add_output_arguments, parse_overrides, topic_name
from vehicle_sim.ros.registry import SIMULATORS, get_simulator, simulator_parameters

__all__ = ["record", "main"]


def record(
    vehicle: str,
    duration: float,
    output: str | Path,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    progress: bool = False,
    overwrite: bool = False,
) -> int:
    """Simulate ``duration`` seconds and write the bag; return the message count.

    ``overwrite`` lets a previous bag at ``output`` be replaced
    (:class:`~terrain_estimation.bag.AtomicBagWriter`); the output is checked
    before any simulation.
    """
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    entry = get_simulator(vehicle)
    ns = namespace if namespace is not None else entry.namespace
    values = simulator_parameters(entry, config, overrides)
    adapter = entry.make_adapter(values, ns)
    topics = {spec.key: topic_name(ns, spec.topic) for spec in adapter.outputs}
    inputs = [config] if config is not None else []
    last = time.monotonic()
    with AtomicBagWriter(output, overwrite=overwrite, inputs=inputs) as writer:
        t = 0.0
        while t < duration - 1e-9:
            t, messages = adapter.step()
            writer.write("/clock", Clock(clock=sec_to_stamp(t)), round(t * 1e9))
            for key, msg in messages:
                writer.write(topics[key], msg, stamp_to_ns(msg.header.stamp))
            if progress and time.monotonic() - last > 2.0:
                last = time.monotonic()
                print(f"  ... {t:.1f} / {duration:.1f} s simulated", file=sys.stderr)
        return writer.count


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-simulate", description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", required=True, choices=sorted(SIMULATORS))
    parser.add_argument("--duration", type=float, required=True, help="simulated seconds")
    add_output_arguments(
        parser,
        output="output bag directory (must not exist)",
        overwrite="replace a previous bag at --output (never anything else)",
        namespace="namespace of the topics (default: the vehicle's)",
    )
    args = parser.parse_args(argv)

    def body() -> int:
        count = record(
            args.vehicle,
            args.duration,
            args.output,
            namespace=args.namespace,
            config=args.config,
            overrides=parse_overrides(args.param),
            progress=True,
            overwrite=args.overwrite,
        )
        print(f"wrote {count} messages ({args.duration:g} s of {args.vehicle}) to {args.output}")
        return EXIT_OK

    return run_cli("terrain-simulate", body, interrupted="interrupted; no bag written")


if __name__ == "__main__":
    sys.exit(main())
