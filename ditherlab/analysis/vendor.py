"""The robot vendor's own force estimate beside ditherlab's: taken from a recording for the
estimates file (:func:`vendor_columns`), and compared with ditherlab's against the same
reference with the same metrics (:func:`compare`).

A recording carries the vendor's estimate as a wrench ``f_vendor_x .. m_vendor_z`` or as
external joint torques ``tau_ext_vendor_j`` (``docs/recording-format.md``); the estimates file
holds it as ``vendor/f_x .. vendor/m_z`` [N, N·m], at ditherlab's tool point in base axes with
the F/T columns' sign. The comparison runs the report's own detection analysis
(:func:`ditherlab.analysis.detection.analyse`) on the vendor's estimate, read as one more
estimator without an interval, so that its noise level, detection thresholds and push errors are
those of the same functions; beside them the force error RMS per axis over all samples and the
bias at rest (the mean of estimate minus reference on the report's rest samples).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.analysis.detection import AXES, CHUNK_ROWS, analyse, condition_of, pushes_and_rest
from ditherlab.core.names import VENDOR
from ditherlab.data.estimates import COMPONENTS, EstimatesSource
from ditherlab.data.recording import Recording

__all__ = ["VENDOR_ESTIMATE_COLUMNS", "compare", "has_vendor", "vendor_columns", "vendor_wrench"]

#: the vendor's estimate in an estimates file, ``vendor/f_x .. vendor/m_z`` [N, N·m]
VENDOR_ESTIMATE_COLUMNS = tuple(f"{VENDOR}/{c}" for c in COMPONENTS)


def vendor_wrench(rec: Recording) -> tuple[np.ndarray, str] | None:
    """The vendor's estimate of the external wrench, (N, 6) [N, N·m] at the tool point in base
    axes with the F/T columns' sign, and where it comes from; None when the recording has none.

    The logged wrench ``f_vendor_*`` when there is one (``"wrench"``); otherwise the wrench
    whose joint torques ``J(q)^T F`` come closest to the logged ``tau_ext_vendor`` (N, n),
    least squares per sample through the pseudo-inverse of ``J^T`` (``"joint torques"``).
    """
    w = rec.vendor_wrench
    if w is not None:
        return w, "wrench"
    tau_ext = rec.tau_ext_vendor
    if tau_ext is None:
        return None
    J = rec.robot().jacobian(rec.q)  # (N, 6, n)
    # pinv of J^T (n x 6) is (6 x n); rcond cuts the directions a singular pose cannot feel
    pinv = np.linalg.pinv(np.transpose(J, (0, 2, 1)), rcond=1e-6)
    return np.einsum("tkj,tj->tk", pinv, tau_ext), "joint torques"


def vendor_columns(rec: Recording) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The estimates file's columns of the vendor's estimate (``vendor/f_x .. vendor/m_z``,
    each (N,) [N, N·m]) and its metadata entry ``{"source": ...}``; both empty without one."""
    got = vendor_wrench(rec)
    if got is None:
        return {}, {}
    w, source = got
    cols = {c: np.ascontiguousarray(w[:, k]) for k, c in enumerate(VENDOR_ESTIMATE_COLUMNS)}
    return cols, {"source": source}


def has_vendor(src: EstimatesSource) -> bool:
    """Whether an estimates file holds the vendor's estimate."""
    return all(c in src.columns for c in VENDOR_ESTIMATE_COLUMNS)


class _VendorView(EstimatesSource):
    """An estimates file seen as if the vendor's estimate were its only estimator variant
    (named :data:`~ditherlab.core.names.VENDOR`), with an interval of NaN (it has none), so that
    the report's analysis reads it as it reads ditherlab's variants."""

    def __init__(self, src: EstimatesSource):
        self._src = src
        self._est = None
        self.name = src.name
        self.meta = {**src.meta, "variants": [VENDOR]}
        self.n_rows = src.n_rows
        self._nan = [f"{VENDOR}/{c}{s}" for c in COMPONENTS for s in ("_lo", "_hi")]
        self.columns = [*src.columns, *self._nan]

    def blocks(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The wrapped file's blocks with the vendor's NaN interval columns added."""
        have = None if columns is None else [c for c in columns if c not in self._nan]
        add = self._nan if columns is None else [c for c in columns if c in self._nan]
        for block in self._src.blocks(rows, have):
            yield block.assign(**dict.fromkeys(add, np.nan))


def compare(
    ests: Sequence[EstimatesSource],
    analysis: dict[str, Any],
    *,
    n_boot: int = 200,
    seed: int = 0,
    rest_margin: float = 1.0,
    chunk_rows: int = CHUNK_ROWS,
) -> dict[str, Any] | None:
    """The vendor's estimate and ditherlab's against the F/T sensor, with the same metrics.

    Parameters
    ----------
    ests : the estimates files of a report (with the F/T columns)
    analysis : their detection analysis (:func:`~ditherlab.analysis.detection.analyse`)
    n_boot, seed, rest_margin, chunk_rows : as for the analysis

    Returns
    -------
    None when no file holds the vendor's estimate; else (JSON-ready) ``reference``, ``files``
    and per estimator (ditherlab's conditions and ``vendor``): ``error_rms`` and ``bias_rest``
    per axis [N], ``noise_level`` per axis [N], per direction ``response_min``,
    ``above10_from``, ``F50``, ``F90`` [N], and ``coverage`` (of the interval at rest; None for
    the vendor's estimate, which has none).
    """
    files = [e for e in ests if has_vendor(e)]
    if not files:
        return None
    with warnings.catch_warnings():  # the interval's width: none, and nanmean says so
        warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)
        vendor = analyse(
            [_VendorView(e) for e in files],
            n_boot=n_boot,
            seed=seed,
            rest_margin=rest_margin,
            chunk_rows=chunk_rows,
        )
    sums: dict[str, _ErrorSums] = {}
    for src in files:
        _add_errors(src, sums, rest_margin, chunk_rows)
    rows = {}
    for cond, c in [*analysis["conditions"].items(), *vendor["conditions"].items()]:
        if cond in sums:
            rows[cond] = {**sums[cond].result(), **_thresholds(c)}
            rows[cond]["coverage"] = None if c["variant"] == VENDOR else c["coverage_rest"]
    return {
        "reference": "F/T sensor (f_x .. m_z)",
        "files": [e.name for e in files],
        "sources": {e.name: e.meta.get("vendor", {}).get("source") for e in files},
        "estimators": rows,
    }


class _ErrorSums:
    """Running sums of estimate minus reference per axis: squared over all samples, plain over
    the rest samples."""

    def __init__(self) -> None:
        self.sse = np.zeros(len(AXES))
        self.n = 0
        self.rest_sum = np.zeros(len(AXES))
        self.n_rest = 0

    def add(self, err: np.ndarray, rest: np.ndarray) -> None:
        """``err`` (m, 3) [N] of m samples, ``rest`` (m,) bool."""
        self.sse += (err**2).sum(axis=0)
        self.n += len(err)
        self.rest_sum += err[rest].sum(axis=0)
        self.n_rest += int(rest.sum())

    def result(self) -> dict[str, Any]:
        rms = np.sqrt(self.sse / self.n) if self.n else np.full(len(AXES), np.nan)
        bias = self.rest_sum / self.n_rest if self.n_rest else np.full(len(AXES), np.nan)
        return {
            "error_rms": dict(zip(AXES, map(float, rms), strict=True)),
            "bias_rest": dict(zip(AXES, map(float, bias), strict=True)),
            "samples": self.n,
            "rest_samples": self.n_rest,
        }


def _add_errors(
    src: EstimatesSource, sums: dict[str, _ErrorSums], rest_margin: float, chunk_rows: int
) -> None:
    """Add one file's force errors of every variant and of the vendor's estimate to ``sums``
    (by condition, as the analysis names them), on the analysis' own rest samples."""
    row, _, _, rest = pushes_and_rest(src, rest_margin, chunk_rows)
    names = [*src.variants, VENDOR]
    a = 0
    for block in src.blocks(chunk_rows):
        b = a + len(block)
        ref = block[list(COMPONENTS[:3])].to_numpy(dtype=float)
        for v in names:
            est = block[[f"{v}/{c}" for c in COMPONENTS[:3]]].to_numpy(dtype=float)
            cond = condition_of(v, row["dithered"])
            sums.setdefault(cond, _ErrorSums()).add(est - ref, rest[a:b])
        a = b


def _thresholds(cond: dict[str, Any]) -> dict[str, Any]:
    """One condition's noise level and per-direction detection thresholds [N]."""
    dirs = {}
    for a in AXES:
        d = cond["directions"].get(a)
        if d is not None:
            dirs[a] = {
                "pushes": d["pushes"],
                "response_min": d["response_min"],
                "above10_from": d["above10_from"],
                "F50": d["curve"]["F50"],
                "F90": d["curve"]["F90"],
            }
    return {"noise_level": cond["noise_level"], "directions": dirs}
