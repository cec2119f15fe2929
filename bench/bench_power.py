"""Power of the diagnosis: how often a planted effect is found, on which joints, against its size
in noise floors, on the built-in plant and the LuGre plant, through the CLI.

Draws come in groups of one seed and one arm (the same plant draw): the clean recording is
simulated and identified once with what the plant always has
(:func:`bench.bench_false_discovery.known_effects`: ``--add inertia``, on the LuGre plant also
``--add stribeck --add ft_drift``, as the false-discovery study does), then each effect of the
group is planted with a drawn size on drawn joints in the same seed's recording and
``diagnose --json`` runs on it with the clean model. Every setting comes from the master seed (``--seed``).

The **size** of an effect on a joint is the RMS of what it adds to the model's residual, divided
by the joint's noise floor. What it adds: the planted recording's logged torque minus the clean
one's (the same seed: the same noise draw), minus ``J(q)^T`` times the change of the F/T reading
(an effect of the sensor, ``ft_bias``, ``ft_drift`` or ``ft_frame``, changes the reading, not the
torque). The floor: on the LuGre plant the recording's ``meta["sim"]["noise_std"]``; on the
built-in plant the noise floor ``diagnose`` reports for the joint (``residual.noise_floor`` of its JSON). On the
LuGre plant the row also holds the metadata's own ``tau_rms / noise_std`` (``meta_floors``: the
logged torque only), and on both what ``diagnose`` sees (``excess_floors``: the growth of the
joint's residual RMS from the clean recording's report to the planted one's, over the floor;
the clean recording is diagnosed once per group).

Per draw and joint where the effect adds at least a quarter of a floor, a row: the size, whether
the effect is **suggested on that joint** (``found``), whether it is the **first** suggestion
(ranked by the share of the residual explained), the joint's p-value, and what else was
suggested. The effects the clean model already holds are not planted: ``inertia`` (both plants'
arms have motor inertia), ``stribeck`` and ``ft_drift`` on the LuGre plant (its friction law
has the curve, its sensor warms up), and ``dither_extraction`` (the draws do not dither: the clean model would hold it).

``python -m bench.bench_power --plant lugre --n N --jobs 2 --out DIR`` writes ``DIR/power.csv``;
``make bench`` runs one group per plant (``quick``: three effects per plant).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from bench.bench_false_discovery import _cli, add_sets, known_effects

#: the master seed of the study's draws (not tuned: the first value tried)
MASTER_SEED = 20261129
#: per plant: effect -> (default size, joints it can be planted on (None: the whole arm))
BAND_EFFECTS: dict[str, tuple[float, bool]] = {
    "load_friction": (0.15, False),
    "drive_gain": (1.1, True),
    "joint_offset": (0.02, True),
    "temperature_friction": (20.0, False),
    "position_ripple": (1.0, False),
    "payload": (2.0, False),
    "attenuation_lag": (0.3, False),
    "stribeck": (0.4, False),
    "ft_bias": (3.0, False),
    "ft_drift": (5.0, False),
    "ft_frame": (5.0, False),
    "dynamics": (0.3, True),
}
LUGRE_EFFECTS: dict[str, tuple[float, bool]] = {
    "viscous": (5.0, True),
    "load_friction": (0.1, True),
    "temperature_friction": (25.0, True),
    "position_ripple": (1.0, True),
    "payload": (2.0, False),
    "attenuation_lag": (0.3, False),
    "ft_bias": (3.0, False),
    "drive_gain": (1.1, True),
    "ft_frame": (5.0, False),
    "dynamics": (0.3, True),
    "joint_offset": (0.02, True),
}
#: the largest size drawn: the plant's own limit, and a sensor turned by at most 20° (the
#: effect's physical range: a larger turn is a frame convention, which no fit may write)
MAX_SIZE = {"joint_offset": 0.1, "attenuation_lag": 0.9, "ft_frame": 20.0}
#: effects diagnosis cannot credit by design, with why: their rows are written and listed, and
#: left out of the share found at 2 floors
ABSORBED = {
    "viscous": "a change of the viscous coefficient is a change of the model's own sliding "
    "line, which diagnosis re-fits beside every effect (as identify does): no effect is "
    "credited with it, and re-identifying on the recording takes it",
}
#: a joint's row is kept when the effect adds at least this many noise floors there
MIN_FLOORS = 0.25


def effects_of(plant: str) -> dict[str, tuple[float, bool]]:
    """The effects ``plant`` can plant: name -> (default size, planted on chosen joints)."""
    return LUGRE_EFFECTS if plant == "lugre" else BAND_EFFECTS


#: per plant and effect: the size in noise floors (:func:`residual_rms` over the floor) of the
#: plant's default size on its largest joint, measured on one seed, the IRB140 (built-in plant:
#: seed 96339, ``--calibrate``, each effect alone, ``dynamics`` on link 5, the sensor effects and
#: ``joint_offset`` on joints 2 and 3 simulated alone; LuGre plant: seed 81991, every effect planted
#: at its default in one recording, each one's ``tau_rms / noise_std`` from the metadata, the two
#: sensor effects alone; ``ft_drift`` on the built-in plant's seed, scaled from ``ft_bias`` by the
#: ratio of their largest joints' :func:`residual_rms`, 0.69). A draw's size is scaled from it
#: so that the largest joint's size is log-uniform over :data:`FLOOR_RANGE`.
FLOORS_AT_DEFAULT: dict[str, dict[str, float]] = {
    "band": {
        "load_friction": 44.1,
        "drive_gain": 2.96,
        "joint_offset": 12.8,
        "temperature_friction": 9.28,
        "position_ripple": 15.0,
        "payload": 36.2,
        "attenuation_lag": 10.2,
        "stribeck": 21.3,
        "ft_bias": 5.04,
        "ft_drift": 3.48,
        "ft_frame": 0.62,
        "dynamics": 33.1,
    },
    "lugre": {
        "viscous": 2.13,
        "load_friction": 22.6,
        "temperature_friction": 13.6,
        "position_ripple": 2.72,
        "payload": 28.9,
        "attenuation_lag": 8.65,
        "ft_bias": 4.13,
        "drive_gain": 24.8,
        "ft_frame": 0.31,
        "dynamics": 53.6,
        "joint_offset": 12.0,
    },
}
#: the span of the largest planted joint's size in noise floors that the draws cover
FLOOR_RANGE = (0.5, 5.0)


def draw_size(plant: str, name: str, default: float, rng: np.random.Generator) -> float:
    """A size of effect ``name`` whose largest joint's size in noise floors is log-uniform over
    :data:`FLOOR_RANGE` (scaled from :data:`FLOORS_AT_DEFAULT`, assumed linear in the size; for
    ``drive_gain``, in the departure from 1), clipped to the plant's largest size."""
    at_default = FLOORS_AT_DEFAULT[plant].get(name, 1.0)
    lo, hi = (np.log(f / at_default) for f in FLOOR_RANGE)
    factor = float(np.exp(rng.uniform(lo, hi)))
    if name == "drive_gain":
        return round(1.0 + (default - 1.0) * factor, 5)
    return float(f"{min(default * factor, MAX_SIZE.get(name, np.inf)):.4g}")


def plan(
    plant: str, n: int, robot: str, master_seed: int = MASTER_SEED, calibrate: bool = False
) -> list[dict[str, Any]]:
    """``n`` draws' settings: groups of one seed with every effect once, in a drawn order
    (``calibrate``: every effect at its plant's default size)."""
    rng = np.random.default_rng([master_seed, 0 if plant == "band" else 1])
    effects = effects_of(plant)
    out: list[dict[str, Any]] = []
    while len(out) < n:
        seed = int(rng.integers(1000, 100000))
        group = len(out) // len(effects)
        for name in rng.permutation(list(effects)):
            default, per_joint = effects[str(name)]
            joints = sorted(
                int(j) for j in rng.choice(6, int(rng.integers(1, 3)), replace=False) + 1
            )
            if plant == "band" and name == "dynamics":
                joints = joints[:1]  # the built-in plant changes one link
            out.append({"id": len(out), "group": group, "plant": plant, "robot": robot,
                        "seed": seed, "effect": str(name), "size": default if calibrate else draw_size(plant, str(name), default, rng),
                        "joints": joints if per_joint else []})  # fmt: skip
    return out[:n]


def _band_config(d: dict[str, Any]) -> str:
    """The built-in plant's TOML placing a per-joint effect on the draw's joints."""
    if not d["joints"]:
        return ""
    if d["effect"] == "dynamics":
        return f"[hidden.dynamics]\nlink = {d['joints'][0]}\n"
    share = [1.0 if j + 1 in d["joints"] else 0.0 for j in range(6)]
    return f"[hidden.{d['effect']}]\nshare = {json.dumps(share)}\n"


def _simulate(d: dict[str, Any], out: Path, hidden: bool) -> str | None:
    """Simulate the draw's recording (``hidden``: with its effect) to ``out``; an error or None."""
    args = ["simulate", "excitation", "-o", out, "--seed", d["seed"], "--no-dither", "-q"]
    args += ["--robot", d["robot"]]
    if d["plant"] == "lugre":
        args += ["--plant", "lugre"]
        at = "@" + ",".join(map(str, d["joints"])) if d["joints"] else ""
        spec = f"{d['effect']}:{d['size']}{at}"
    else:
        spec = f"{d['effect']}:{d['size']}"
        cfg = out.with_suffix(".toml")
        cfg.write_text(_band_config(d) if hidden else "")
        args += ["--config", cfg]
    if hidden:
        args += ["--hidden", spec]
    r = _cli(*args, "--force")
    return None if r.returncode == 0 else "simulate: " + r.stderr.strip()[-300:]


class Clean:
    """The clean recording and its identified model of each group, made once (thread-safe)."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.locks: dict[int, threading.Lock] = {}
        self.done: dict[int, str | None] = {}
        self.lock = threading.Lock()

    def get(self, d: dict[str, Any]) -> tuple[Path, Path, str | None]:
        """(clean recording, its model, an error or None) of draw ``d``'s group."""
        g = d["group"]
        folder = self.work / f"g{g:03d}"
        with self.lock:
            lock = self.locks.setdefault(g, threading.Lock())
        with lock:
            if g not in self.done:
                folder.mkdir(parents=True, exist_ok=True)
                self.done[g] = self._make(d, folder)
        return folder / "clean.parquet", folder / "model.toml", self.done[g]

    def _make(self, d: dict[str, Any], folder: Path) -> str | None:
        err = _simulate(d, folder / "clean.parquet", hidden=False)
        if err:
            return err
        for adds in add_sets(known_effects(d["plant"], sensor=True)):
            flags = [a for e in adds for a in ("--add", e)]
            r = _cli("identify", folder / "clean.parquet", *flags, "--bootstrap", "0",
                     "-o", folder / "model.toml", "-q", "--force")  # fmt: skip
            if r.returncode == 0:
                break
        if r.returncode != 0:
            return "identify: " + r.stderr.strip()[-300:]
        r = _cli("diagnose", folder / "clean.parquet", "--model", folder / "model.toml",
                 "--json", "--no-history", "-q")  # fmt: skip
        if r.returncode != 0:
            return "diagnose clean: " + r.stderr.strip()[-300:]
        (folder / "clean.json").write_text(r.stdout)
        return None


WRENCH = ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")


def _columns(path: Path) -> dict[str, np.ndarray]:
    """(N, 6) [rad] ``q``, [N·m] ``tau`` and, where logged, [N, N·m] ``wrench`` of a recording."""
    import pyarrow.parquet as pq

    t = pq.read_table(path)
    have = set(t.column_names)
    out = {
        k: np.column_stack([t.column(f"{k}_{j}").to_numpy() for j in range(1, 7)])
        for k in ("q", "tau")
    }
    if set(WRENCH) <= have:
        out["wrench"] = np.column_stack([t.column(c).to_numpy() for c in WRENCH])
    return out


def _meta_sim(path: Path) -> dict[str, Any]:
    import pyarrow.parquet as pq

    return json.loads(pq.read_schema(path).metadata[b"ditherlab"])["sim"]


def residual_rms(rec: Path, clean: Path, robot: str) -> np.ndarray:
    """(6,) [N·m] per joint, the RMS of what the effect adds to the model's residual: the logged
    torque's change minus ``J(q)^T`` times the F/T reading's change (base-frame axes), and minus
    the change of the gravity torque at the logged angles where they differ by more than 0.1 mrad;
    the planted recording against the clean one of the same seed (the same noise draw)."""
    from ditherlab.robot import RobotModel

    a, b = _columns(rec), _columns(clean)
    m = min(len(a["tau"]), len(b["tau"]))
    d = a["tau"][:m] - b["tau"][:m]
    arm = RobotModel.from_spec(robot)
    if "wrench" in a and "wrench" in b:
        dw = a["wrench"][:m] - b["wrench"][:m]
        if np.abs(dw).max() > 0:
            d = d - np.einsum("tkn,tk->tn", arm.jacobian(b["q"][:m]), dw)
    if np.abs(a["q"][:m] - b["q"][:m]).max() > 1e-4:  # a logged angle that is off (encoders)
        d = d - (arm.gravity(a["q"][:m]) - arm.gravity(b["q"][:m]))
    return np.sqrt(np.mean(d**2, axis=0))


def sizes(d: dict[str, Any], rec: Path, clean: Path, report: dict) -> tuple[np.ndarray, str]:
    """(6,) the effect's size per joint in noise floors (:func:`residual_rms` over the floor),
    and where the floor comes from."""
    rms = residual_rms(rec, clean, d["robot"])
    if d["plant"] == "lugre":
        return rms / np.asarray(_meta_sim(rec)["noise_std"]), "noise_std of the plant's metadata"
    return rms / np.asarray(report["residual"]["noise_floor"]), "diagnose's noise floor"


def metadata_floors(d: dict[str, Any], rec: Path) -> list[float] | None:
    """LuGre plant: the recording's own ``tau_rms / noise_std`` of the planted effect (the
    logged torque only, without the F/T reading's change)."""
    if d["plant"] != "lugre":
        return None
    sim = _meta_sim(rec)
    truth = next(h for h in sim["hidden"] if h["name"] == d["effect"])
    return [round(float(v), 3) for v in np.asarray(truth["tau_rms"]) / np.asarray(sim["noise_std"])]


def excess_floors(planted: dict, clean: dict) -> np.ndarray:
    """(6,) what ``diagnose`` sees of the effect per joint: the growth of its residual's RMS,
    ``sqrt(max(r_planted² - r_clean², 0))``, over the planted recording's noise floor (both
    from the reports' ``residual``)."""
    rp = np.asarray(planted["residual"]["torque_rms"])
    rc = np.asarray(clean["residual"]["torque_rms"])
    return np.sqrt(np.maximum(rp**2 - rc**2, 0.0)) / np.asarray(planted["residual"]["noise_floor"])


def _named(c: dict[str, Any], j: int) -> bool:
    """Whether candidate ``c`` is suggested on 1-based joint ``j`` (a shared effect with no
    joints listed: on every joint)."""
    return bool(c["suggested"]) and (not c["joints"] or j in c["joints"])


def _p_value(c: dict[str, Any] | None, j: int) -> float | None:
    if c is None:
        return None
    for pj in c.get("per_joint") or []:
        if pj.get("joint") in (j, "all"):
            return pj.get("p_value")
    return None


def rows_of(d: dict[str, Any], report: dict, floors: np.ndarray, source: str) -> list[dict]:
    """The draw's rows: one per joint where the effect adds at least :data:`MIN_FLOORS`."""
    sug = sorted((c for c in report["candidates"] if c["suggested"]),
                 key=lambda c: -c["explained_fraction"])  # fmt: skip
    mine = next((c for c in report["candidates"] if c["effect"] == d["effect"]), None)
    first = sug[0]["effect"] if sug else ""
    base = {k: d[k] for k in ("id", "group", "plant", "robot", "seed", "effect", "size")}
    base["planted_joints"] = ",".join(map(str, d["joints"])) or "arm"
    base["size_source"] = source
    base["first"] = first
    base["suggested"] = ";".join(f"{c['effect']}@{c['joints']}" for c in sug)
    base["not_identifiable"] = (mine or {}).get("not_identifiable") or ""
    out = []
    for j in range(1, 7):
        if not floors[j - 1] >= MIN_FLOORS:
            continue
        found = mine is not None and _named(mine, j)
        out.append({**base, "joint": j, "floors": round(float(floors[j - 1]), 3),
                    "found": found, "found_first": found and first == d["effect"],
                    "p_value": _p_value(mine, j), "error": ""})  # fmt: skip
    return out


def one(d: dict[str, Any], clean: Clean) -> list[dict[str, Any]]:
    """Simulate the draw's planted recording, diagnose it with its group's clean model; its rows."""
    rec_clean, model, err = clean.get(d)
    fail = {k: d[k] for k in ("id", "group", "plant", "robot", "seed", "effect", "size")}
    if err:
        return [{**fail, "error": err}]
    rec = rec_clean.parent / f"d{d['id']:03d}-{d['effect']}.parquet"
    err = _simulate(d, rec, hidden=True)
    if err:
        return [{**fail, "error": err}]
    r = _cli("diagnose", rec, "--model", model, "--json", "--no-history", "-q")
    if r.returncode != 0:
        return [{**fail, "error": "diagnose: " + r.stderr.strip()[-300:]}]
    report = json.loads(r.stdout)
    (rec.with_suffix(".json")).write_text(r.stdout)
    floors, source = sizes(d, rec, rec_clean, report)
    meta = metadata_floors(d, rec)
    rec.unlink()  # the recording is regenerated from its settings; its report is kept
    excess = excess_floors(report, json.loads((rec_clean.parent / "clean.json").read_text()))
    rows = rows_of(d, report, floors, source)
    for r in rows:
        r["meta_floors"] = "" if meta is None else meta[r["joint"] - 1]
        r["excess_floors"] = round(float(excess[r["joint"] - 1]), 3)
    return rows or [{**fail, "error": "", "joint": ""}]


def study(draws: list[dict[str, Any]], work: Path, jobs: int = 1) -> tuple[list[dict], float]:
    """Run ``draws`` in ``work`` with ``jobs`` at a time; (rows in draw order, wall time [s])."""
    t0 = time.perf_counter()
    clean, rows = Clean(work), []
    with ThreadPoolExecutor(jobs) as pool:
        futs = [pool.submit(one, d, clean) for d in draws]
        for k, f in enumerate(as_completed(futs), 1):
            got = f.result()
            rows += got
            write_csv(rows, work / "power.csv")  # the rows so far: a stopped run keeps them
            g = got[0]
            what = g.get("error") or ", ".join(
                f"j{r['joint']} {r['floors']:.2f} fl {'found' if r['found'] else 'missed'}"
                for r in got if r.get("joint")) or "below a quarter floor on every joint"  # fmt: skip
            print(f"  [{k}/{len(draws)}] {g['plant']} d{g['id']:03d} {g['effect']}:{g['size']} "
                  f"{g['robot']} seed {g['seed']}: {what}", file=sys.stderr, flush=True)  # fmt: skip
    return sorted(rows, key=lambda r: (r["id"], r.get("joint") or 0)), time.perf_counter() - t0


#: size bins [noise floors] of the detection-rate table
BINS = (0.25, 0.5, 1.0, 2.0, 5.0, np.inf)


def rates(rows: list[dict[str, Any]]) -> dict[tuple[str, str], list[tuple[int, int]]]:
    """(plant, effect) -> per bin of :data:`BINS`: (joints found, joints planted)."""
    out: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for r in rows:
        if r.get("error") or r.get("joint") in ("", None):
            continue
        cell = out.setdefault((r["plant"], r["effect"]), [(0, 0)] * (len(BINS) - 1))
        k = int(np.searchsorted(BINS, float(r["floors"]), side="right")) - 1
        f, m = cell[k]
        cell[k] = (f + _true(r["found"]), m + 1)
    return out


def _true(v: Any) -> int:
    return int(v is True or str(v) == "True")


def at_two_floors(rows: list[dict[str, Any]]) -> tuple[int, int]:
    """(found, planted) over every joint where an effect is at least 2 noise floors (the
    effects diagnosis cannot credit by design, :data:`ABSORBED`, left out)."""
    keep = [r for r in rows if not r.get("error") and r.get("joint") not in ("", None)]
    keep = [r for r in keep if r["effect"] not in ABSORBED]
    big = [r for r in keep if float(r["floors"]) >= 2.0]
    return sum(_true(r["found"]) for r in big), len(big)


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))  # every column, first-seen order
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        w.writerows(rows)


def run(quick: bool = False) -> list[dict]:
    out = []
    for plant in ("band", "lugre"):
        n = 3 if quick else len(effects_of(plant))
        work = Path(tempfile.mkdtemp(prefix="ditherlab-power-"))
        try:
            rows, wall = study(plan(plant, n, "irb140"), work, jobs=2)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        found, planted = at_two_floors(rows)
        out += [
            {"name": f"power, {plant}: joints found at >= 2 noise floors", "value": found,
             "unit": f"of {planted}", "target": ">= 90 %"},
            {"name": f"power study wall time, {plant} ({n} draws)", "value": wall, "unit": "s"},
        ]  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plant", choices=("band", "lugre"), default="band")
    ap.add_argument("--robot", default="irb140", help="the simulated arm (simulate --robot)")
    ap.add_argument(
        "--n", type=int, default=24, help="draws (groups of one seed, each effect once)"
    )
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=MASTER_SEED, help="master seed of every draw")
    ap.add_argument("--out", type=Path, required=True, help="folder for power.csv and the runs")
    ap.add_argument("--calibrate", action="store_true", help="every effect at its default size")
    ap.add_argument("--only", type=lambda v: {int(x) for x in v.split(",")},
                    help="comma-separated draw ids to run (e.g. 4,6)")  # fmt: skip
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    draws = plan(a.plant, max(a.only) + 1 if a.only else a.n, a.robot, a.seed, a.calibrate)
    draws = [d for d in draws if not a.only or d["id"] in a.only]
    rows, wall = study(draws, a.out, a.jobs)
    write_csv(rows, a.out / "power.csv")
    found, planted = at_two_floors(rows)
    print(f"wall time {wall:.0f} s", file=sys.stderr)
    print(
        json.dumps(
            {"draws": len(draws), "found_at_2_floors": found, "planted_at_2_floors": planted}
        )
    )


if __name__ == "__main__":
    main()
