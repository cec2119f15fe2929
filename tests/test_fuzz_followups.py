"""The fuzz campaign's hard cases outside the readers: a mapped CSV whose first line is far wider
than the rest (refused at once, not parsed for minutes), pandas' two-line message (one line), a
one-row log without a stated rate in identify and diagnose (one line, no traceback), and a
report that fails after writing figures (no partial folder left)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import DATA, run_cli

from ditherlab.core.files import all_or_nothing

UR = DATA / "ur10e" / "no_torque.csv"


@pytest.fixture
def ur_csv(tmp_path):
    if not UR.is_file():
        pytest.skip("UR10e test data not found")
    return UR.read_text(encoding="utf-8").splitlines(keepends=True)


def test_mapped_csv_with_a_first_line_far_wider_is_refused_at_once(tmp_path, ur_csv):
    """A first line of 200 000 extra fields is refused before pandas would parse every row that
    wide (> 60 s)."""
    lines = list(ur_csv)
    lines[0] = lines[0].rstrip("\n") + ",0" * 200_000 + "\n"
    f = tmp_path / "wide.csv"
    f.write_text("".join(lines), encoding="utf-8")
    r = run_cli("info", f, "--mapping", "ur10e")
    assert r.code == 2
    head = lines[1].count(",") + 1
    assert r.err.startswith(
        f"error: {f}: line 1 has {head + 200_000} fields but line 2 has {head}; expected the same "
        "number of fields on every line (as described by "
    )
    assert r.err.count("\n") == 1


def test_pandas_message_of_a_mapped_csv_is_one_line(tmp_path, ur_csv):
    lines = list(ur_csv)
    lines[40] = lines[40].rstrip("\n") + ",1,2,3\n"
    f = tmp_path / "ragged.csv"
    f.write_text("".join(lines), encoding="utf-8")
    r = run_cli("convert", f, tmp_path / "out.parquet", "--mapping", "ur10e")
    assert r.code == 2
    assert r.err.count("\n") == 1 and "Error tokenizing data" in r.err
    assert r.err.rstrip().endswith(")") and not (tmp_path / "out.parquet").exists()


@pytest.fixture(scope="module")
def one_row(tmp_path_factory):
    """A valid one-row recording without sample_rate_hz, and a model to diagnose it with."""
    d = tmp_path_factory.mktemp("one")
    assert run_cli("simulate", "push-campaign", "--seed", "3", "--pushes-per-direction", "1",
                   "-o", d / "sim.parquet").code == 0  # fmt: skip
    assert run_cli("identify", d / "sim.parquet", "-o", d / "m.toml", "--bootstrap", "0").code == 0
    t = pq.read_table(d / "sim.parquet")
    meta = json.loads(t.schema.metadata[b"ditherlab"])
    meta.pop("sample_rate_hz", None)
    one = t.slice(0, 1).replace_schema_metadata({b"ditherlab": json.dumps(meta).encode()})
    pq.write_table(one, d / "one.parquet")
    return d


def test_identify_of_one_row_without_a_rate_is_one_line(one_row, tmp_path):
    r = run_cli("identify", one_row / "one.parquet", "-o", tmp_path / "m.toml", "--bootstrap", "0")
    assert r.code == 2
    assert r.err.splitlines()[-1] == (
        f"error: {one_row / 'one.parquet'}: no joint has 200 samples in any regime (still, "
        "dither, moving); record longer"
    )
    assert "Traceback" not in r.err


def test_diagnose_of_one_row_without_a_rate_is_one_line(one_row, tmp_path):
    r = run_cli("diagnose", one_row / "one.parquet", "--model", one_row / "m.toml",
                "--no-history", "-o", tmp_path / "diag")  # fmt: skip
    assert r.code == 2
    assert r.err.splitlines()[-1] == (
        f"error: {one_row / 'one.parquet'}: no sample left to score (1 rows; stick transitions, "
        "velocity reversals and the first dither period are not scored); expected a longer "
        "recording"
    )
    assert not (tmp_path / "diag").exists()


def test_report_that_fails_late_leaves_no_folder(one_row, tmp_path):
    """The recording's q_2 has an infinite value: the pieces' check meets it only when the
    torque figures are drawn, after the first figures were written; nothing may stay."""
    rec, est = one_row / "sim.parquet", tmp_path / "est.parquet"
    assert run_cli("replay", rec, "--model", one_row / "m.toml", "-o", est, "-q").code == 0
    t = pq.read_table(rec)
    df = t.to_pandas()
    df.loc[len(df) // 2, "q_2"] = np.inf
    bad = pa.Table.from_pandas(df, preserve_index=False).replace_schema_metadata(t.schema.metadata)
    pq.write_table(bad, tmp_path / "bad.parquet")
    out = tmp_path / "report"
    r = run_cli("report", est, "--recording", tmp_path / "bad.parquet", "-o", out,
                "--bootstrap", "5")  # fmt: skip
    assert r.code == 2
    assert "q_2" in r.err.splitlines()[-1] and r.err.splitlines()[-1].startswith("error: ")
    assert not out.exists()


def test_all_or_nothing_removes_only_what_the_block_created(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "old.txt").write_text("kept", encoding="utf-8")
    with pytest.raises(RuntimeError), all_or_nothing(out):
        (out / "new.txt").write_text("x", encoding="utf-8")
        (out / "sub").mkdir()
        (out / "sub" / "f.png").write_bytes(b"png")
        raise RuntimeError("late failure")
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError), all_or_nothing(fresh):
        fresh.mkdir()
        (fresh / "a").write_text("x", encoding="utf-8")
        raise RuntimeError
    assert not fresh.exists()
    with all_or_nothing(fresh):  # no error: everything stays
        fresh.mkdir()
        (fresh / "a").write_text("x", encoding="utf-8")
    assert (fresh / "a").read_text(encoding="utf-8") == "x"
    shutil.rmtree(fresh)
