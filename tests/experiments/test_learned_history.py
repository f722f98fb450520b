"""Learned block history: each experiment's history variants start with the blocks the fleet
reported in the intruder runs of the EARLIER experiments on the same map (campaign order), never
its own or a later one's; checked against fresh simulations (lab, 10 robots, solver time zero)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.campaign import (
    Blocks,
    CampaignError,
    CampaignSpec,
    InstanceRecord,
    SimSettings,
    learned_histories,
    load_grid,
    open_executor,
    read_blocks,
    read_results,
    run_campaign,
    simulate_variant,
)
from gateway.runtime.mapstore import resolve

MAPS = {"lab": str(resolve("lab", "map"))}
LEARNED = SimSettings(solver_time="zero", learned_blocks=100)
SPEC = CampaignSpec(groups=(("lab", 10),), instances=1, seeds=3, sim=LEARNED,
                    plan_time_limit_s=20, extra_variants=("informed", "shadow"))


def test_a_history_holds_the_last_blocks_of_earlier_experiments_on_the_same_map() -> None:
    k0, k1, k2, k3, k4 = (("lab", 5, 0, 1), ("lab", 5, 0, 2), ("arena", 5, 0, 1),
                          ("lab", 5, 1, 1), ("arena", 5, 0, 2))
    blocks = {k0: Blocks(k0, (1.0, 2.0)), k1: Blocks(k1, (3.0,)), k2: Blocks(k2, (9.0,)),
              k3: Blocks(k3, (4.0,)), k4: Blocks(k4, ())}
    got = learned_histories([k0, k1, k2, k3, k4], blocks, 2)
    assert got == {k0: (), k1: (1.0, 2.0), k2: (), k3: (2.0, 3.0), k4: (9.0,)}
    # Once an earlier experiment's blocks are unknown, later ones on that map have no history.
    del blocks[k1]
    assert learned_histories([k0, k1, k2, k3, k4], blocks, 2) == {
        k0: (), k1: (1.0, 2.0), k2: (), k4: (9.0,)}


@pytest.fixture(scope="module")
def learned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("learned")
    with open_executor(2) as (pool, n):
        # interrupted after two experiments' first phase, then resumed
        first = run_campaign(SPEC, out, MAPS, executor=pool, workers=n, limit=2)
        assert not first.complete
        assert run_campaign(SPEC, out, MAPS, executor=pool, workers=n).complete
    return out


def test_each_experiment_starts_from_the_blocks_of_the_earlier_ones_only(learned: Path) -> None:
    rows = {r.key: r for r in read_results(learned / "results.csv")}
    recorded = read_blocks(learned / "blocks.csv")
    rec = json.loads((learned / "instances" / "lab-10-000.json").read_text())
    plan = InstanceRecord.from_json(rec).plan
    grid = load_grid(MAPS["lab"])
    cold = SimSettings(solver_time="zero")
    history: tuple[float, ...] = ()
    differs = 0
    for m, n, i, seed in SPEC.experiments():
        # what the fleet reported in this experiment's intruder run, simulated afresh
        mine = simulate_variant(grid, plan, seed, "intruder", cold).blocks_ms
        assert recorded[(m, n, i, seed)].durations_ms == pytest.approx(mine, abs=1e-3)
        for variant in ("informed", "shadow"):
            expect = simulate_variant(grid, plan, seed, variant, cold, history)
            row = rows[(m, n, i, seed, variant)]
            assert (row.soc_ms, row.makespan_ms) == pytest.approx(
                (expect.soc_ms, expect.makespan_ms), abs=1e-3), (seed, variant)
            # (its own blocks, as often as a full history (100 blocks) would hold them:
            # shadow adopts a plan that may lose only on that much evidence)
            wrong = simulate_variant(grid, plan, seed, variant, cold, history + mine * 100)
            differs += (wrong.soc_ms, wrong.makespan_ms) != (expect.soc_ms, expect.makespan_ms)
        if not history:  # the first experiment: exactly the cold run
            assert rows[(m, n, i, seed, "shadow")].soc_ms == pytest.approx(
                simulate_variant(grid, plan, seed, "shadow", cold).soc_ms, abs=1e-3)
        history += mine
    # The check can tell: its own blocks in the history would change some run.
    assert differs > 0
    assert history  # the intruder blocked someone


def test_a_folder_keeps_its_block_history(learned: Path) -> None:
    cold = CampaignSpec(SPEC.groups, 1, 3, sim=SimSettings(solver_time="zero"),
                        plan_time_limit_s=20, extra_variants=SPEC.extra_variants)
    with (open_executor(1) as (pool, n),
          pytest.raises(CampaignError, match="learned_blocks: 100 there, 0 now")):
        run_campaign(cold, learned, MAPS, executor=pool, workers=n)


def test_history_settings_are_free_while_no_row_depends_on_them(tmp_path: Path) -> None:
    plain = CampaignSpec(SPEC.groups, 1, 1, sim=SimSettings(solver_time="zero"),
                         plan_time_limit_s=20)
    with open_executor(1) as (pool, n):
        run_campaign(plain, tmp_path, MAPS, executor=pool, workers=n)
        (tmp_path / "blocks.csv").unlink()  # a folder made before blocks were recorded
        spec = CampaignSpec(SPEC.groups, 1, 1, sim=LEARNED, plan_time_limit_s=20,
                            extra_variants=("shadow",))
        res = run_campaign(spec, tmp_path, MAPS, executor=pool, workers=n)
    assert res.complete
    rows = read_results(tmp_path / "results.csv")
    assert sorted(r.variant for r in rows) == sorted(("lower_bound", "intruder", "random",
                                                      "slack", "shadow"))
    assert len(read_blocks(tmp_path / "blocks.csv")) == 1  # the intruder run was re-run


def test_learned_and_given_histories_exclude_each_other() -> None:
    with pytest.raises(CampaignError, match="learned or given"):
        CampaignSpec(SPEC.groups, 1, 1, sim=SimSettings(learned_blocks=5,
                                                        block_history_ms=(5100.0,)))
