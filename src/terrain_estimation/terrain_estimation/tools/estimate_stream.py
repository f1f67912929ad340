"""``terrain-estimate`` writes each estimate to its output bag as it is made (issue 23, memory).

A run that kept its estimates until the end held them all (about 250 MB per 15 min of the skid steer's 200 Hz
estimates) and then serialised them at once. :class:`StreamedEstimates` is the replay's sink instead
(:func:`terrain_estimation.tools.estimate.estimate_to_bag`): each estimate goes to the
:class:`~terrain_estimation.bag.AtomicBagWriter` as the replay makes it, in the same order, with the same
log time, so the bag holds the same messages as before; what the printed summary needs is kept as it goes:
per estimate topic its count and its last message, and the comparison with the ground truth read in the same
pass (:class:`~terrain_estimation.tools.estimate_truth.TruthTally`: running sums).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from terrain_estimation.tools.estimate_truth import TruthTally

__all__ = ["StreamedEstimates"]


class StreamedEstimates:
    """The sink of a streamed run: writes every estimate and keeps what the summary prints.

    Args:
        writer: an open :class:`~terrain_estimation.bag.AtomicBagWriter` (anything with
            ``write(topic, msg, log_time_ns)``).

    The run says which ground truth it compares with (:meth:`expect`) before the first estimate.
    """

    def __init__(self, writer: Any) -> None:
        self.writer = writer
        self.counts: dict[str, int] = {}  # estimate topic -> estimates written
        self.last: dict[str, Any] = {}  # estimate topic -> its last estimate
        self.truth_topics: dict[str, str] = {}  # ground-truth topic -> estimate topic
        self.tallies: dict[str, TruthTally] = {}  # estimate topic -> its comparison with ground truth

    def expect(
        self, truth_topics: Mapping[str, str], truth_fields: Mapping[str, tuple[str, ...]], present: Collection[str]
    ) -> None:
        """The ground truth to compare with.

        Args:
            truth_topics: ground-truth topic -> the estimate topic it checks (all of them are read in the
                replay's pass, as the summary of a run in memory reads them: their undecodable messages count).
            truth_fields: estimate topic -> its compared fields (a topic with none is not compared).
            present: the ground-truth topics the bag holds messages on (only these are compared: an estimate
                waits for the truth that follows it, and with no truth at all it would wait to the end).
        """
        self.truth_topics = dict(truth_topics)
        self.tallies = {
            estimate: TruthTally(truth_fields[estimate])
            for truth, estimate in truth_topics.items()
            if truth in present and truth_fields.get(estimate)
        }

    def __call__(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """One estimate, as the replay keeps it: written, counted, compared."""
        self.writer.write(topic, msg, log_time_ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.last[topic] = msg
        tally = self.tallies.get(topic)
        if tally is not None:
            tally.estimate(msg)

    def truth(self, truth_topic: str, msg: Any) -> None:
        """One decoded ground-truth message, in recorded order."""
        tally = self.tallies.get(self.truth_topics[truth_topic])
        if tally is not None:
            tally.truth(msg)

    def truth_errors(self) -> dict[str, dict[str, tuple[float, float, float]]]:
        """Estimate topic -> field -> (RMS, final absolute, final relative error), of every topic written."""
        return {t: (self.tallies[t].figures() if t in self.tallies else {}) for t in sorted(self.counts)}

    @property
    def written(self) -> int:
        return sum(self.counts.values())
