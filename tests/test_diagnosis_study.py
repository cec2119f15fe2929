"""The diagnosis studies' plans and their page: bench/bench_power.py, the LuGre families of
bench/bench_false_discovery.py and scripts/diagnosis_study_page.py.

The plans must be reproducible from their master seed, plant only what the plant can plant at
sizes it accepts, and never plant what the clean model holds; the page's numbers must be the
counts of the rows it was given.
"""

from __future__ import annotations

import csv
import importlib.util
import math
import re
from pathlib import Path

import numpy as np

from bench import bench_false_discovery as fdr
from bench import bench_power as bp

REPO = Path(__file__).resolve().parents[1]


def _page_module():
    spec = importlib.util.spec_from_file_location(
        "diagnosis_study_page", REPO / "scripts" / "diagnosis_study_page.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_power_plan_reproducible_every_effect_once_per_seed():
    for plant in ("band", "lugre"):
        n = 3 * len(bp.effects_of(plant))
        a, b = bp.plan(plant, n, "irb140"), bp.plan(plant, n, "irb140")
        assert a == b
        assert a != bp.plan(plant, n, "irb140", master_seed=bp.MASTER_SEED + 1)
        for g in range(3):
            group = [d for d in a if d["group"] == g]
            assert sorted(d["effect"] for d in group) == sorted(bp.effects_of(plant))
            assert len({d["seed"] for d in group}) == 1
        assert len({d["seed"] for d in a}) == 3


def test_power_plan_plants_only_what_the_plant_can_and_the_model_lacks():
    from ditherlab.sim.hidden import EFFECTS as BAND
    from ditherlab.sim_lugre import EFFECTS as LUGRE

    assert set(bp.effects_of("band")) <= set(BAND)
    assert set(bp.effects_of("lugre")) <= set(LUGRE)
    # what the clean model identifies is never planted
    for plant in ("band", "lugre"):
        known = fdr.known_effects(plant, sensor=True)
        assert "inertia" in known and not set(known) & set(bp.effects_of(plant))
    assert {"stribeck", "ft_drift"} <= set(fdr.known_effects("lugre", sensor=True))
    assert "ft_drift" not in fdr.known_effects("lugre", sensor=False)
    for plant in ("band", "lugre"):
        for d in bp.plan(plant, 60, "irb140"):
            assert d["size"] > 0
            assert d["size"] <= bp.MAX_SIZE.get(d["effect"], math.inf)
            if d["effect"] == "drive_gain":
                assert d["size"] > 1.0
            assert all(1 <= j <= 6 for j in d["joints"])
            assert bool(d["joints"]) == bp.effects_of(plant)[d["effect"]][1]


def test_power_sizes_span_the_floor_range():
    """Scaled from the calibration, the largest joint's expected size covers 0.5..5 floors."""
    rng = np.random.default_rng(0)
    for plant in ("band", "lugre"):
        for name, (default, _) in bp.effects_of(plant).items():
            if name in bp.MAX_SIZE or name == "drive_gain":
                continue
            at = bp.FLOORS_AT_DEFAULT[plant].get(name, 1.0)
            floors = [bp.draw_size(plant, name, default, rng) / default * at for _ in range(400)]
            assert min(floors) >= bp.FLOOR_RANGE[0] * 0.999
            assert max(floors) <= bp.FLOOR_RANGE[1] * 1.001
            assert np.quantile(floors, 0.1) < 1.0 and np.quantile(floors, 0.9) > 2.5


def test_lugre_false_discovery_families_both_arms_and_their_commands(tmp_path):
    plan = fdr.plan_lugre(2 * len(fdr.LUGRE_FAMILIES))
    assert plan == fdr.plan_lugre(2 * len(fdr.LUGRE_FAMILIES))
    seen = {(s["family"], s["robot"]) for s in plan}
    assert seen == {(f, r) for f in fdr.LUGRE_FAMILIES for r in fdr.LUGRE_ROBOTS}
    for s in plan:
        assert s["hidden"] == []
        args = [str(a) for a in fdr._simulate_args(s, tmp_path / "r.parquet", tmp_path / "c.toml")]
        assert args[args.index("--plant") + 1] == "lugre"
        assert args[args.index("--robot") + 1] == s["robot"]
        loads = [args[i + 1] for i, a in enumerate(args) if a == "--external-load"]
        assert loads == ([s["family"]] if s["family"] in ("cable", "hose", "hand") else [])
        assert s["no_sensor"] == (s["scenario"] == "standing")
    # the built-in plan is unchanged by the LuGre one
    assert [s["family"] for s in fdr.plan(7)] == list(fdr.FAMILIES)


def _write(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        w.writerows(rows)


def test_page_counts_are_the_rows(tmp_path):
    mod = _page_module()
    fd = [{"id": i, "family": "moving", "plant": "lugre", "robot": "ur10e", "seed": 5 + i,
           "false_discovery": i == 3, "suggested": "viscous@[2]" if i == 3 else "", "error": ""}
          for i in range(9)]  # fmt: skip
    power = []
    for i, (floors, found) in enumerate([(0.3, False), (0.7, False), (1.5, True), (2.5, True),
                                          (3.0, False), (7.0, True)]):  # fmt: skip
        power.append({"id": i, "group": 0, "plant": "band", "robot": "irb140", "seed": 11,
                      "effect": "payload", "size": 1.0, "planted_joints": "arm", "first": "payload",
                      "suggested": "payload@[2]" if found else "", "not_identifiable": "",
                      "joint": 2, "floors": floors, "found": found, "found_first": found,
                      "p_value": 0.001, "error": ""})  # fmt: skip
    _write(tmp_path / "fd" / "study.csv", fd)
    _write(tmp_path / "pw" / "power.csv", power)
    out = tmp_path / "page.md"
    fdr_rows = mod.read_rows([tmp_path / "fd"], "study.csv")
    pw_rows = mod.read_rows([tmp_path / "pw"], "power.csv")
    mod.figure(pw_rows, out.with_suffix(".png"))
    text = mod.page(fdr_rows, pw_rows, "page.png")
    assert "| LuGre plant | moving | ur10e | 9 | 1 | r003 seed 8: viscous@[2] |" in text
    bound = 100 * mod.upper95(1, 9)
    assert f"| LuGre plant | 9 | 1 | {bound:.1f} % |" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("| built-in plant | payload |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # bins 0.25-0.5, 0.5-1, 1-2, 2-5, >= 5; then >= 2 found, >= 2 named first
    assert cells[2:] == ["0/1", "0/1", "1/1", "1/2", "1/1", "2/3", "2/3"]
    assert re.search(r"payload size 1\.0, joint 2 at 3\.00 floors.*not suggested", text)
    assert out.with_suffix(".png").stat().st_size > 1000
