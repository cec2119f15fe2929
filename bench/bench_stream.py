"""Peak memory of the commands that read in pieces, on a log of one hour and on one of ten.

The logs: the built-in simulator's dithered push campaign, one hour at 250 Hz (seed 11), and
that hour tiled ten times end to end (time stamps shifted; the seams are jumps in ``q`` that
read as a moment of motion). Each command runs as a user runs it (``python -m ditherlab``, a
fresh process) and its peak resident memory is read from the kernel (``ru_maxrss`` of the
child). The target: peak memory independent of the log's length, under
2 GB for ten hours.

``python -m bench.bench_stream --hours 10 --keep DIR`` keeps the logs; ``--only identify`` runs
one command. ``view`` and ``report`` read the logs' estimates (replayed once, not timed); the
ten-hour view writes a 13 GB ``.rrd`` (removed after).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _hour(path: Path, seconds: float) -> None:
    from ditherlab.io import write
    from ditherlab.sim import simulate

    per = max(int(seconds / (2.8 * 6)), 2)
    rec = simulate("push-campaign", seed=11, dither=True, pushes_per_direction=per)
    write(rec.slice(None, rec.t[0] + seconds), path)


def _tile(src: Path, dst: Path, times: int) -> None:
    """``src`` repeated ``times`` times, time stamps continued (read and written in pieces)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(src, pre_buffer=False)
    t = pf.read(columns=["t"]).column("t").to_numpy()
    span = float(t[-1] - t[0]) + float(t[1] - t[0])
    schema = pf.schema_arrow.with_metadata(
        {**(pf.schema_arrow.metadata or {}), **(pf.metadata.metadata or {})}
    )
    part = dst.with_suffix(".part")
    with pq.ParquetWriter(part, schema, compression="zstd") as w:
        for k in range(times):
            for batch in pf.iter_batches(batch_size=131_072):
                cols = {n: batch.column(n) for n in batch.schema.names}
                cols["t"] = pa.array(batch.column("t").to_numpy() + k * span)
                w.write_table(pa.table(cols, schema=schema), row_group_size=131_072)
    part.replace(dst)


def _rows(path: Path) -> int:
    import pyarrow.parquet as pq

    return int(pq.ParquetFile(path).metadata.num_rows)


#: run a command from a small process and print its peak RSS [kB]: a child forked straight from
#: this (large) benchmark process would report this process's peak as its own, since Linux
#: keeps ``ru_maxrss`` across ``fork`` and ``exec`` (every figure read 4070 MB in one run)
_LAUNCH = (
    "import os, subprocess, sys\n"
    "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)\n"
    "err = p.stderr.read()\n"
    "_, status, usage = os.wait4(p.pid, 0)\n"
    "sys.stderr.buffer.write(err)\n"
    "print(usage.ru_maxrss)\n"
    "sys.exit(os.waitstatus_to_exitcode(status))\n"
)


def _peak(args: list[str]) -> tuple[float, float]:
    """(wall seconds, peak RSS [MB]) of ``python -m ditherlab ARGS`` in a fresh process, started
    by a small launcher process (:data:`_LAUNCH`) that reads the child's own ``ru_maxrss``."""
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _LAUNCH, sys.executable, "-m", "ditherlab", *args],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode:
        raise RuntimeError(f"ditherlab {' '.join(args)}: {proc.stderr.strip()}")
    return time.perf_counter() - t0, int(proc.stdout.split()[-1]) / 1024.0


def run(
    quick: bool = False, hours: float = 10.0, keep: Path | None = None, only: str | None = None
) -> list[dict]:
    from ditherlab.analysis.identification import identify
    from ditherlab.sim import simulate

    seconds = 360.0 if quick else 3600.0
    times = 3 if quick else int(round(hours))
    with tempfile.TemporaryDirectory() as tmp:
        d = keep or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        one, many = d / "one.parquet", d / "many.parquet"
        if not one.exists():
            _hour(one, seconds)
        if not many.exists():
            _tile(one, many, times)
        model = d / "model.toml"
        if not model.exists():
            ident = [
                simulate("push-campaign", seed=12, dither=x, pushes_per_direction=4)
                for x in (False, True)
            ]
            identify(ident, n_boot=0).save(model)
        rows = []
        for name, args in (
            ("info", ["info", "{rec}", "--json"]),
            ("convert to Parquet", ["convert", "{rec}", "{out}.parquet"]),
            (
                "replay, four variants",
                ["replay", "{rec}", "--model", str(model), "-o", "{out}.est.parquet", "-q"],
            ),
            ("identify, 30 bootstrap replicates", ["identify", "{rec}", "-o", "{out}.toml", "-q"]),
            (
                "diagnose, 13 candidates",
                ["diagnose", "{rec}", "--model", str(model), "--no-history", "--json", "-q"],
            ),
            (
                "view with estimates and model to .rrd",
                ["view", "{rec}", "--estimates", "{est}", "--model", str(model)]
                + ["--save", "{out}.rrd", "-q"],
            ),
            (
                "report with the recording",
                ["report", "{est}", "--recording", "{rec}", "-o", "{out}", "-q"],
            ),
        ):
            if only is not None and not name.startswith(only):
                continue
            res = {}
            for label, rec in (("short", one), ("long", many)):
                slug = name.split()[0].strip(",")
                out = d / f"{label}_{slug}"
                est = d / f"{label}.estimates.parquet"  # replayed once, for view and report
                if any("{est}" in x for x in args) and not est.exists():
                    _peak(["replay", str(rec), "--model", str(model), "-o", str(est), "-q"])
                a = [x.format(rec=rec, out=out, est=est) for x in args]
                res[label] = _peak(a)
                for f in d.glob(f"{label}_{slug}*"):
                    if f.is_file():
                        os.remove(f)
                    elif f.is_dir():
                        shutil.rmtree(f)
            dur_s = seconds * times / 3600
            rows.append(
                {
                    "name": f"{name}: peak memory, {dur_s:g} h log (vs {seconds / 3600:g} h)",
                    "value": res["long"][1],
                    "unit": "MB",
                    "reference": res["short"][1],
                    "ratio": res["short"][1] / res["long"][1],
                    "target": "<= 2048 MB for 10 h, independent of length",
                }
            )
            rows.append(
                {
                    "name": f"{name}: wall time, {dur_s:g} h log",
                    "value": res["long"][0],
                    "unit": "s",
                    "reference": res["short"][0],
                }
            )
            if name.startswith("diagnose"):  # the rate target on a long log
                n_long = _rows(many)
                rows.append(
                    {
                        "name": f"diagnose: samples per second of wall time, {dur_s:g} h log",
                        "value": n_long / res["long"][0],
                        "unit": "samples/s",
                        "reference": _rows(one) / res["short"][0],
                        "target": ">= 50 k samples/s on long logs, linear",
                    }
                )
        return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--hours", type=float, default=10.0)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--keep", type=Path)
    ap.add_argument("--only", help="run the commands whose name starts with this (e.g. identify)")
    a = ap.parse_args()
    for row in run(quick=a.quick, hours=a.hours, keep=a.keep, only=a.only):
        ref = f" (1 h: {row['reference']:.4g})" if row.get("reference") is not None else ""
        print(f"{row['name']:<70} {row['value']:>10.4g} {row['unit']}{ref}")
