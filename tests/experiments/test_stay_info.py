"""The information bound: the clairvoyant's sweep with the fleet's first report of the block."""

from __future__ import annotations

import dataclasses

import pytest

from experiments.campaign import PlanTask, SimSettings, load_grid, plan_instance, variant_config
from experiments.oracle import sweep
from experiments.stay_info import report_sweep
from gateway.runtime.mapstore import resolve
from sim_clients.des import Simulation

MAP = str(resolve("lab", "map"))


@pytest.mark.parametrize(("stay", "seed"), [("uniform:1-30", 1154091980), ("lognormal:5,1", 3),
                                            ("lognormal:5,1", 852974580)])
def test_the_report_sweep_is_the_clairvoyants_with_the_first_report(stay: str,
                                                                    seed: int) -> None:
    rec = plan_instance(PlanTask("lab", MAP, 5, 0, 0, 20.0))
    config = variant_config(load_grid(MAP), rec.plan, seed, "intruder",
                            SimSettings(solver_time="zero", intruder_stay=stay))
    got = report_sweep(config, 500.0)
    assert got.sweep.curve == sweep(config, 500.0, clairvoyant=True).curve
    # the first report, read independently: when the executor's block tracker opened the
    # intruder's cell in a run without replanning, watched every 100 ms
    watch = Simulation(dataclasses.replace(config, policy="none"))
    watch.start()
    opened, t = None, 0.0
    while not watch.finished() and opened is None:
        t += 100.0
        watch.run_until(t)
        intr = watch.intruder
        if intr is not None and intr.cell in watch.executor.blocks.open:
            opened = watch.executor.blocks.open[intr.cell]
    assert got.first_report_ms == opened
    assert watch.intruder is not None and got.stay_ms == watch.intruder.config.stay_ms
    if opened is None:  # (seed 852974580: a stay of 0.67 s, over before any robot came)
        assert got.saving_ms(from_report=True) == 0.0
        return
    assert opened >= config.intruder_config.appear_ms
    # the savings, by hand from the curve
    after = [s for t, s in got.sweep.curve if t >= opened]
    none = got.sweep.none_soc_ms
    assert got.saving_ms(from_report=True) == max(0.0, none - min(after, default=none))
    assert got.saving_ms() == max(0.0, none - min(s for _, s in got.sweep.curve))
    assert got.saving_ms(from_report=True) <= got.saving_ms()
