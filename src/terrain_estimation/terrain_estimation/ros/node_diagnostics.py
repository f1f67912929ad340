"""The estimator node's health on ``/diagnostics``: one DiagnosticStatus per period.

What :class:`EstimatorDiagnostics` reports (the node,
:class:`~terrain_estimation.ros.framework.EstimatorNode`, keeps the state it
reads): the update rate and the age of the last update, the innovations'
consistency (windowed mean NIS against its chi-square band), the adapter's
warnings and errors (:attr:`AdapterHealth.warnings
<terrain_estimation.ros.adapters.AdapterHealth.warnings>`, ``.errors``),
rejected input, non-finite estimates not published, estimator restarts, clock
jumps and silent input topics.
"""

from __future__ import annotations

import math
from typing import Any

from terrain_estimation.ros import diagnostics as diag
from terrain_estimation.ros.adapter_node import AdapterNode
from terrain_estimation.ros.adapters import EstimatorAdapter
from terrain_estimation.ros.validation import InputGuard

__all__ = ["EstimatorDiagnostics"]


class EstimatorDiagnostics(AdapterNode[EstimatorAdapter]):
    """The diagnostics of an estimator node (a base of :class:`~terrain_estimation.ros.framework.EstimatorNode`)."""

    # Kept by the node: its input checks, what it dropped or restarted, clock jumps, silence.
    guard: InputGuard
    restarts: dict[str, int]
    outputs_dropped: dict[str, int]
    clock_jumps: dict[str, int]
    last_reset: str
    _jump_note: str
    _updates_at_jump: int
    _rejected_reported: int
    _last_updates: int
    _last_receipt: dict[str, float]
    _watch_from: float | None
    _silent: set[str]
    _diag_pub: Any

    def _clock_s(self) -> float | None:
        """The node's clock in seconds, None while it does not run (the node's)."""
        raise NotImplementedError

    def _throttled(self, reason: str, line: str, level: str = "warn") -> None:
        """Log ``line`` at most once per ``input.log_throttle`` per ``reason`` (the node's)."""
        raise NotImplementedError

    def diagnostic_status(self) -> diag.DiagnosticStatus:
        """The node's health as one DiagnosticStatus (also used by tests)."""
        health = self.adapter.health
        now = self.get_clock().now().nanoseconds * 1e-9
        level = diag.OK
        notes: list[str] = []
        values: dict[str, Any] = {"updates": health.updates}
        if health.last_update_time is None:
            level = diag.WARN
            notes.append("no filter update yet")
        else:
            age = now - health.last_update_time
            values["last_update_age_s"] = age
            if age > float(self.values["diagnostics.stale_after"]):
                level = diag.WARN
                notes.append(f"last update {age:.2f} s ago")
        period = float(self.values["diagnostics.period"])
        rate = (health.updates - self._last_updates) / period
        self._last_updates = health.updates
        values["update_rate_hz"] = rate
        if health.nis:
            n = len(health.nis)
            mean_nis = sum(health.nis) / n
            p = float(self.values["diagnostics.nis_probability"])
            # The sum of n independent NIS values is chi-square with n*dof degrees of freedom: a two-sided band
            # on their mean. On a real vehicle (or any plant richer than the model) the innovations are
            # coloured by the model error, and n correlated values carry only n/tau independent ones (tau: the
            # window's integrated autocorrelation time, Geyer's initial positive sequence); a band of n would
            # WARN on every healthy run. A fault (a sensor offset, a stuck input) moves the mean by far more.
            # Imported here, at the first diagnostics with NIS samples: the analysis package pulls scipy.special
            # and scipy.linalg in, which the offline replay and a node's start-up need not wait for (issue 23).
            from terrain_estimation.analysis.consistency import chi2_mean_band, integrated_autocorrelation_time

            tau = integrated_autocorrelation_time(list(health.nis)) if n >= 8 else 1.0
            lo, hi = chi2_mean_band(health.nis_dof, n / tau, p)
            # The model tolerance (diagnostics.nis_tolerance): a predicted innovation variance a few per cent
            # off is not a fault; the statistical band of a long window is narrower than that.
            tolerance = float(self.values["diagnostics.nis_tolerance"])
            lo, hi = lo * (1.0 - tolerance), hi * (1.0 + tolerance)
            values.update(nis_mean=mean_nis, nis_band_low=lo, nis_band_high=hi, nis_window=n, nis_tau=tau)
            if not math.isfinite(mean_nis) or mean_nis > hi or mean_nis < lo:
                level = diag.worst(level, diag.WARN)
                notes.append(f"innovations inconsistent (mean NIS {mean_nis:.2f} outside [{lo:.2f}, {hi:.2f}])")
        if health.warnings:
            level = diag.worst(level, diag.WARN)
            notes.extend(health.warnings)
        if health.errors:
            level = diag.worst(level, diag.ERROR)
            notes[:0] = health.errors
        for reason, count in health.rejected.items():
            values[f"rejected: {reason}"] = count
        level = self._input_diagnostics(level, notes, values, now)
        values.update(health.values)
        message = "; ".join(notes) if notes else (health.status or "estimating")
        return diag.make_status(
            f"{self.get_fully_qualified_name()}: estimator",
            self.get_namespace().strip("/") or self.get_name(),
            level,
            message,
            values,
        )

    def _input_diagnostics(self, level: bytes, notes: list[str], values: dict[str, Any], now: float) -> bytes:
        """Rejected input, dropped output, silent topics and clock jumps (part of :meth:`diagnostic_status`)."""
        guard = self.guard
        total = sum(guard.rejected.values())
        values["input_accepted"] = guard.accepted
        values["input_rejected"] = total
        for reason, count in guard.rejected.items():
            values[f"input rejected: {reason}"] = count
        new = total - self._rejected_reported
        self._rejected_reported = total
        if new > 0:
            level = diag.worst(level, diag.WARN)
            notes.append(f"{new} input messages rejected since the last report")
        for reason, count in self.restarts.items():
            values[f"estimator restarts: {reason}"] = count
        if self.outputs_dropped:
            level = diag.worst(level, diag.ERROR)
            notes.insert(0, f"{sum(self.outputs_dropped.values())} non-finite estimates not published")
            for reason, count in self.outputs_dropped.items():
                values[f"output dropped: {reason}"] = count
        values["clock_jumps_backward"] = self.clock_jumps["backward"]
        values["clock_jumps_forward"] = self.clock_jumps["forward"]
        if self.last_reset:
            values["last_reset"] = self.last_reset
        if self._jump_note and self.adapter.health.updates > self._updates_at_jump:
            self._jump_note = ""  # estimating again
        if self._jump_note:
            level = diag.worst(level, diag.WARN)
            notes.append(self._jump_note)
        if self._clock_s() is None:
            return level  # sim time before /clock: silence cannot be measured
        if self._watch_from is None:
            self._watch_from = now
        silent = []
        for spec in self.adapter.inputs:
            if spec.timeout <= 0.0:
                continue
            age = now - self._last_receipt.get(spec.key, self._watch_from)
            if age > spec.timeout:
                silent.append(spec.topic)
                level = diag.worst(level, diag.WARN)
                what = "silent" if spec.key in self._last_receipt else "never received"
                note = f"{spec.topic} {what} for {age:.3g} s (timeout {spec.timeout:g} s)"
                notes.append(note + (f": {spec.on_timeout}" if spec.on_timeout else ""))
                if spec.key not in self._silent:
                    self._silent.add(spec.key)
                    self._throttled(f"silent {spec.key}", note)
            elif spec.key in self._silent:
                self._silent.discard(spec.key)
                self.get_logger().info(f"{spec.topic} resumed")
        values["silent_topics"] = ", ".join(silent) if silent else "none"
        return level

    def publish_diagnostics(self) -> None:
        self._diag_pub.publish(diag.make_array(self.get_clock().now().to_msg(), [self.diagnostic_status()]))
