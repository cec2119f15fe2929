"""``ditherlab report``: analyse estimates files (the paper's §VI-C detection statistics,
:func:`ditherlab.analysis.detection.analyse`) and write the report folder
(:func:`ditherlab.output.report_page.write_pages`). Nothing is written when the analysis fails
(no F/T columns, no pushes)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.detection import NoPushesError, NoRestError, analyse
from ditherlab.analysis.known_load import known_load_analysis
from ditherlab.analysis.no_sensor import no_sensor_analysis
from ditherlab.analysis.vendor import compare
from ditherlab.app.workflow import Progress, as_recording, guard
from ditherlab.core.files import all_or_nothing, check_not_input
from ditherlab.data.estimates import Estimates, EstimatesSource
from ditherlab.data.recording import Recording
from ditherlab.io.stream import CHUNK_ROWS
from ditherlab.output.known_load_page import (
    known_load_blocks,
    known_load_lines,
    write_known_load_pages,
)
from ditherlab.output.no_sensor_page import no_sensor_lines, write_no_sensor_pages
from ditherlab.output.report_page import open_logs, summary_text, write_pages
from ditherlab.output.vendor_page import vendor_text

__all__ = ["ReportOptions", "Reported", "make_report", "run"]


@dataclass(frozen=True)
class ReportOptions:
    """The options of ``ditherlab report``.

    Attributes
    ----------
    estimates : estimates files from ``ditherlab replay`` (with the F/T columns), or
        :class:`~ditherlab.data.estimates.Estimates` in memory
    out : the report folder (``report.md``, ``report.html``, ``report.json``, PNG figures)
    recordings : the recordings behind the estimates (files or Recording objects): with them
        the torque figures (Figs. 2, 4, 5) are drawn too
    n_boot : bootstrap replicates of the detection curves
    seed : the bootstrap's seed
    chunk_rows : rows read at a time from a file
    force : write into an existing non-empty folder
    paper : show the paper's IRB140 table for any robot (it is shown for the IRB140 always;
        otherwise the user's own variants are compared)
    """

    estimates: tuple[str | Path | Estimates, ...]
    out: str | Path
    recordings: tuple[str | Path | Recording, ...] = ()
    n_boot: int = 200
    seed: int = 0
    chunk_rows: int = CHUNK_ROWS
    force: bool = False
    paper: bool = False


@dataclass
class Reported:
    """What :func:`run` wrote: the analysis (as in ``report.json``) and the report folder."""

    analysis: dict[str, Any]
    out: Path

    def text(self) -> str:
        """What the CLI prints: the paper's table, the known load's comparison, the folder."""
        if "no_sensor" in self.analysis:
            return "\n".join([*no_sensor_lines(self.analysis["no_sensor"]), f"wrote {self.out}"])
        known = self.analysis.get("known_load")
        lines = known_load_lines(known) if known else []
        if "recordings" not in self.analysis:  # a known load's report without pushes
            return "\n".join([*lines, f"wrote {self.out}"])
        return "\n".join([self._text(), *lines])

    def _text(self) -> str:
        """The paper's table beside ours and where the report went (what the CLI prints)."""
        vendor = vendor_text(self.analysis)
        return (
            summary_text(self.analysis)
            + (f"\n{vendor}" if vendor else "")
            + f"\nwrote {self.out}/report.md"
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output: the analysis."""
        return self.analysis


def run(options: ReportOptions, progress: Progress | None = None) -> Reported:
    """Analyse the estimates and write the report folder, all or nothing.

    Parameters
    ----------
    options : :class:`ReportOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    Reported
    """
    o = options
    files = [x for x in (*o.estimates, *o.recordings) if isinstance(x, str | Path)]
    out = guard(o.out, files, folder=True, force=o.force)
    with all_or_nothing(out):
        analysis = make_report(
            o.estimates,
            out,
            recordings=o.recordings,
            n_boot=o.n_boot,
            seed=o.seed,
            chunk_rows=o.chunk_rows,
            progress=progress,
            paper=o.paper,
        )
    return Reported(analysis, out)


def make_report(
    estimates: Sequence[str | Path | Estimates],
    out_dir: str | Path,
    *,
    recordings: Sequence[Recording | str | Path] = (),
    n_boot: int = 200,
    seed: int = 0,
    figures: bool = True,
    chunk_rows: int = CHUNK_ROWS,
    progress: Progress | None = None,
    paper: bool = False,
) -> dict[str, Any]:
    """Analyse estimates and write the report folder.

    Estimates files and recording files are read ``chunk_rows`` rows at a time: the analysis
    (:func:`ditherlab.analysis.detection.analyse`) keeps the pushes, the per-push numbers and
    counts, the figures only the stretches they show (a window of rows around them), so memory
    does not grow with the logs' length beyond about 17 bytes per sample; the numbers do not
    depend on ``chunk_rows``.

    Parameters
    ----------
    estimates : estimates files (or loaded :class:`~ditherlab.data.estimates.Estimates`)
    out_dir : folder to write (created; files written atomically)
    recordings : the recordings (Recording objects or paths) behind the estimates, optional:
        with them the torque figures (Figs. 2, 4, 5) are drawn too
    n_boot, seed : bootstrap of the detection curves
    figures : draw the PNG figures
    chunk_rows : rows read at a time from a file (:data:`ditherlab.io.stream.CHUNK_ROWS`)
    progress : ``progress(done, total)``
    paper : the paper's IRB140 table for any robot (always for the IRB140; otherwise the
        estimates' own variants are compared)

    Returns
    -------
    The analysis dict (as written to ``report.json``), with ``files`` listing what was written.

    Raises
    ------
    NoPushesError
        No F/T columns or no pushes: nothing is written.
    """
    out = Path(out_dir)
    ests = [
        EstimatesSource.of(e) if isinstance(e, Estimates) else EstimatesSource(e) for e in estimates
    ]
    for e in estimates:
        if not isinstance(e, Estimates):
            check_not_input(out / "report.json", [e])
    # the recordings opened (and their time stamps read) before anything is written; each one
    # must be behind one of the estimates (as ``view --estimates`` requires)
    logs = open_logs(recordings, ests, chunk_rows) if figures else []
    steps = 3 + (4 if figures else 0)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    known = known_load_analysis(ests, chunk_rows)
    if known is None and ests and not any(e.has_wrench for e in ests):
        return _no_sensor_report(ests, recordings, out)  # the estimator on its own terms
    try:
        analysis = analyse(ests, n_boot=n_boot, seed=seed, chunk_rows=chunk_rows)
    except (NoPushesError, NoRestError) as err:
        if known is None:
            raise
        # a run with a known load and no pushes to judge: the estimate against the load alone
        if isinstance(err, NoRestError):
            known["no_table"] = (
                "the log has pushes but no rest: the noise level every detection is judged "
                "against is measured at rest"
            )
        return _known_load_report(ests, known, out)
    vendor = compare(ests, analysis, n_boot=n_boot, seed=seed, chunk_rows=chunk_rows)
    if vendor is not None:
        analysis["vendor"] = vendor
    tick()
    analysis["paper_comparison"] = paper or _robot_name(ests) == "irb140"
    extra = []
    if known is not None:
        analysis["known_load"] = known
        extra = known_load_blocks(known, _level_text(ests))
    write_pages(
        ests, analysis, logs, out, figures=figures, chunk_rows=chunk_rows, tick=tick, extra=extra
    )
    return analysis


def _no_sensor_report(
    ests: Sequence[EstimatesSource], recordings: Sequence[Recording | str | Path], out: Path
) -> dict[str, Any]:
    """The report of estimates without F/T columns (:mod:`ditherlab.analysis.no_sensor`): with
    the recordings behind them, the thresholds predicted at their rest pose too."""
    open_logs(recordings, ests)  # each recording must be behind one of the estimates
    robots = []
    for r in recordings:
        rec = as_recording(r)
        robots.append((rec.robot(), np.median(rec.q, axis=0)))
    analysis = no_sensor_analysis(ests, robots=robots)
    write_no_sensor_pages(ests, analysis, _level_text(ests), out)
    return {"no_sensor": analysis}


def _robot_name(ests: Sequence[EstimatesSource]) -> str | None:
    """The robot's name in the first estimates file's recording metadata, or None."""
    robot = (ests[0].meta.get("recording") or {}).get("robot") if ests else None
    if isinstance(robot, dict):
        return robot.get("name")
    return robot if isinstance(robot, str) else None


def _level_text(ests: Sequence[EstimatesSource]) -> str:
    """``95% profile``: the intervals' level and method."""
    level = ests[0].meta.get("interval", {})
    return f"{level.get('level', 0.95):.0%} {level.get('method', '')}".strip()


def _known_load_report(
    ests: Sequence[EstimatesSource], known: dict[str, Any], out: Path
) -> dict[str, Any]:
    """The report of estimates without pushes whose recordings declare a known load: the
    estimate against the load's wrench alone."""
    analysis: dict[str, Any] = {"known_load": known}
    write_known_load_pages([e.name for e in ests], analysis, _level_text(ests), out)
    return analysis
