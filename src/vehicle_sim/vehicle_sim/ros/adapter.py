"""What the simulator adapters share: the step that turns a plant sample into messages.

Each vehicle's adapter (:mod:`vehicle_sim.ros.quarter_car`,
:mod:`~vehicle_sim.ros.skid_steer`, :mod:`~vehicle_sim.ros.rover`) builds its
plant from validated parameters and defines ``messages(sample)``; the
simulator node (:class:`terrain_estimation.ros.simulator_node.SimulatorNode`) and
``terrain-simulate`` call :meth:`SimAdapter.step`. The helpers that declare and read
parameters (frame names, a dataclass's fields, the kind check) are the core's,
:mod:`terrain_estimation.ros.parameters`: the estimators' adapters use them too.
"""

from __future__ import annotations

from typing import Any

__all__ = ["SimAdapter"]


class SimAdapter:
    """Base of the adapters: ``simulator.step()`` gives a sample with its time ``t``, ``messages`` its messages."""

    simulator: Any

    def messages(self, sample: Any) -> list[tuple[str, Any]]:
        raise NotImplementedError

    def step(self) -> tuple[float, list[tuple[str, Any]]]:
        """Advance the plant one sample; its time (s) and its messages in publication order."""
        sample = self.simulator.step()
        return sample.t, self.messages(sample)
