"""What the clairvoyant's saving owes to knowing the intruder's cell before any robot reports it.

The clairvoyant yardstick (:func:`experiments.oracle.sweep` with ``clairvoyant``) forces one
informed replan every ``step_ms`` from ``T_a``, each knowing the intruder's cell and leave
time, and keeps the best. A policy that runs online learns the cell only from the fleet: the
first report of a robot blocked by the intruder. Until then every policy runs the same plan
as not replanning (or replans without knowing the block, which the uninformed oracle bounds).

:func:`report_sweep` runs the same sweep and also notes that first report, so one sweep gives
the clairvoyant's saving and the saving of the same yardstick allowed to act only from the
report -- still knowing the stay exactly. No policy that learns the cell from the report and
the stay from the block's end can do better than that with the yardstick's plans (informed
solves): it gets the same choices with less knowledge. Its capture of the clairvoyant's
saving is therefore an upper bound on every online policy's capture, whatever it does while
the block lasts (decisions at any time, any number of switches, any assumed stay).
"""

from __future__ import annotations

from dataclasses import dataclass

from experiments.oracle import ClairvoyantSimulation, Memo, Sweep, sweep_from
from sim_clients.des import SimConfig
from sim_clients.robot import RobotEvent
from sim_clients.world import INTRUDER


class _Reported(ClairvoyantSimulation):
    """A clairvoyant sweep's base run that notes the first report of a robot blocked by the
    intruder."""

    first_report_ms: float | None = None

    def robot_events(self, events: list[RobotEvent]) -> None:
        if self.first_report_ms is None:
            for e in events:
                d = self.robots[e.robot].current
                if e.kind == "blocked" and d is not None \
                        and INTRUDER in self.world.holders(d.dst):
                    self.first_report_ms = e.t_ms
                    break
        super().robot_events(events)


@dataclass(frozen=True)
class ReportSweep:
    """One experiment's clairvoyant sweep and when the fleet first reported the block."""

    sweep: Sweep
    first_report_ms: float | None
    """The first report of a robot blocked by the intruder (None: no robot was)."""
    stay_ms: float | None
    """The experiment's drawn stay (None: the paper's fixed leave time)."""

    def saving_ms(self, from_report: bool = False) -> float:
        """The clairvoyant's saving against not replanning (``from_report``: its replans at
        or after the first report only; none if no robot reported the block)."""
        if not from_report:
            return self.sweep.none_soc_ms - self.sweep.best()[0]
        if self.first_report_ms is None:
            return 0.0
        return self.sweep.none_soc_ms - self.sweep.best(self.first_report_ms)[0]


def report_sweep(config: SimConfig, step_ms: float) -> ReportSweep:
    """The clairvoyant sweep of ``config`` (policy none, a replan budget; as
    :func:`experiments.oracle.sweep`) with the first report of the block."""
    if not step_ms > 0:
        raise ValueError(f"the sweep's step must be positive, got {step_ms}")
    base = _Reported(config, Memo())
    got = sweep_from(base, step_ms, clairvoyant=True)
    intr = base.intruder
    return ReportSweep(got, base.first_report_ms, None if intr is None else intr.config.stay_ms)
