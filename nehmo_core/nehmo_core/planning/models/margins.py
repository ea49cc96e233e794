"""Certified margins: the level ``V ≥ margin`` each pair model's rows of Opt keep.

With certified margins (``PlannerSettings.margins.certified``), rows against a peer at full speed
keep ε: the largest of the floor (the settings' ε) and every ``δ`` the cards of the planner's
models certify (``nehmo verify``) at ``t_safe``. Rows against a peer that announced a speed bound,
planned at time-to-go ``bound·t_safe``, keep ``max(settled floor, δ)`` of their own model's
certificate at that horizon (the settled floor is ``settled_epsilon``; with no certificate at
exactly that horizon, the next longer certified one; see
:meth:`~nehmo_core.planning.models.value_model.PairValueModel.certified_margin`), never more than ε.
Full-speed rows keep one ε for every model: with each model's own ``δ`` instead (0.05 m for the
five-UR5 cell's 0.849 m and 1.2 m pairs against 0.083 m for its 0.6 m pairs, then on 10M-sample
models), the centre arm was squeezed into contact in a closed loop where one ε kept it clear
(seed 0, scenario 38).
Without certified margins every row keeps the settings' ε (the paper's fixed margin).
"""

from __future__ import annotations

from collections.abc import Sequence

from nehmo_core.planning.models.value_model import PairValueModel


class CertifiedMargins:
    """Margins of one planner's models; ``used``: the indices of the models its pairs map onto;
    ``epsilon`` [m] the floor (raised to the certified δ at ``t_safe`` [s] when ``certified``),
    ``settled_epsilon`` [m] the floor of rows against a peer that announced a bound."""

    def __init__(
        self,
        models: Sequence[PairValueModel],
        used: Sequence[int],
        epsilon: float,
        settled_epsilon: float,
        t_safe: float,
        certified: bool = True,
        actuators: str = "ideal",
    ) -> None:
        self.models = list(models)
        self.floor = epsilon
        self.settled_floor = settled_epsilon
        self.t_safe = t_safe
        self.certified = certified
        self.actuators = actuators  # the actuator model whose certificates count
        self.epsilon, self.source = self._reported(sorted(set(used)))
        self._cache: dict[tuple[int, float], float] = {}

    def _reported(self, used: list[int]) -> tuple[float, str]:
        """The reported ε and a line saying where it came from."""
        if not self.certified:
            return self.floor, f"ε = {self.floor:g} m, fixed"
        levels = {
            self.models[i].name: self.models[i].certified_level(self.t_safe, self.actuators)
            for i in used
        }
        certified = {name: d for name, d in levels.items() if d is not None}
        missing = sorted(name for name, d in levels.items() if d is None)
        epsilon = max([self.floor, *certified.values()])
        deltas = ", ".join(f"{name} {d:.4g}" for name, d in sorted(certified.items()))
        note = f"ε = {epsilon:.4g} m: max(floor {self.floor:g}"
        if self.actuators != "ideal":
            ideal = [
                self.models[i].name
                for i in used
                if not self.models[i].certified_under(self.actuators)
            ]
            fallback = f"; ideal-tracking certificates for {', '.join(ideal)}" if ideal else ""
            note = f"[{self.actuators} actuators{fallback}] {note}"
        note += f", certified δ at t_safe {self.t_safe:g} s: {deltas})" if deltas else ")"
        note += (
            f"; rows against a settled peer keep max({self.settled_floor:g}, their model's δ at"
            " that horizon)"
        )
        if missing:
            note += f"; no certificate at t_safe for: {', '.join(missing)}"
        return epsilon, note

    def group(self, model_index: int, bound: float) -> float:
        """The margin [m] of model ``model_index``'s rows against peers planned at ``bound`` of
        full speed (time-to-go ``bound·t_safe``): ε at full speed, for a model without a
        certificate that long, or without certified margins."""
        key = (model_index, bound)
        if key not in self._cache:
            slow = self.certified and bound < 1.0
            model = self.models[model_index]
            found = model.certified_margin(bound * self.t_safe, self.actuators) if slow else None
            margin = (
                self.epsilon if found is None else min(self.epsilon, max(self.settled_floor, found))
            )
            self._cache[key] = margin
        return self._cache[key]
