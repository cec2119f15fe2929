"""``ditherlab leadthrough``: the simulator's lead-through with the 10 N dead zone against the
confidence interval (paper §V) on the same operator pushes, measured
(:func:`ditherlab.analysis.lead_metrics.lead_metrics`), averaged over seeds
(:func:`ditherlab.analysis.lead_metrics.law_means`) and written as a Markdown table, the JSON of
every run and a figure (:func:`ditherlab.output.lead_figures.write_comparison`).

With ``--model`` the admittance is driven by ``ditherlab live``'s estimate with that torque
model, computed in this process; with ``--live`` too by a ``ditherlab live`` process over DDS in
lock-step (:mod:`ditherlab.app.leadthrough_live`), and the same runs in one process are the
reference it is checked against (``result["closed_loop"]``)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ditherlab.analysis.lead_metrics import law_means, lead_metrics, means_table, path_trace
from ditherlab.app.leadthrough_live import (
    causal_source,
    closed_loop_difference,
    closed_loop_line,
    link_settings,
)
from ditherlab.app.workflow import Progress, guard
from ditherlab.core.errors import ConfigError
from ditherlab.core.files import all_or_nothing
from ditherlab.data.torque_model import TorqueModel
from ditherlab.output.lead_figures import write_comparison
from ditherlab.sim import simulate
from ditherlab.sim.params import LEAD_THROUGH_LAWS, load_params

__all__ = ["DITHER_CHOICES", "LeadthroughOptions", "Compared", "compare_laws", "run"]

#: ``--dither``: the dither settings compared
DITHER_CHOICES = {"both": (True, False), "on": (True,), "off": (False,)}


@dataclass(frozen=True)
class LeadthroughOptions:
    """The options of ``ditherlab leadthrough``.

    Attributes
    ----------
    out : the output folder (``.md``, ``.json``, ``.png``)
    seed : the first simulator seed (each seed fixes the push magnitudes and the noise)
    repeats : runs per law and dither setting, on seeds ``seed, seed + 1, ...``
    dither : ``both``, ``on`` or ``off`` (:data:`DITHER_CHOICES`)
    config : a simulator TOML every run starts from
    force : write into an existing non-empty folder
    model : a torque model (TOML): ``ditherlab live``'s estimate with it drives the admittance
        (None: the controller's own eq. (3))
    live : that estimate from a ``ditherlab live`` process over DDS, in lock-step
    namespace : the ROS 2 namespace of the live runs' topics (None: one of this process's own)
    domain : the DDS domain (None: ``ROS_DOMAIN_ID``, else 0)
    """

    out: str | Path
    seed: int = 0
    repeats: int = 3
    dither: str = "both"
    config: Path | None = None
    force: bool = False
    model: Path | None = None
    live: bool = False
    namespace: str | None = None
    domain: int | None = None


@dataclass
class Compared:
    """What :func:`run` compared (:func:`compare_laws`'s result) and the files it wrote."""

    result: dict[str, Any]
    files: list[Path]

    def text(self) -> str:
        """The means table and the files written (what the CLI prints)."""
        loop = self.result.get("closed_loop")
        check = f"\n{closed_loop_line(loop)}" if loop else ""
        return means_table(self.result) + check + f"\nwrote {', '.join(map(str, self.files))}"


def run(
    options: LeadthroughOptions,
    progress: Progress | None = None,
    dds: Callable[..., AbstractContextManager[Any]] | None = None,
) -> Compared:
    """Check the options and the output folder, compare the laws and write the comparison,
    all or nothing.

    Parameters
    ----------
    options : :class:`LeadthroughOptions`
    progress : ``progress(done, total)``, optional
    dds : with ``live``: :func:`ditherlab.app.leadthrough_dds.dds_source` (the CLI passes it
        once the DDS library is known to be installed)

    Returns
    -------
    Compared
    """
    o = options
    if o.dither not in DITHER_CHOICES:
        raise ConfigError(f"--dither: got {o.dither!r}; expected 'both', 'on' or 'off'")
    if o.live and o.model is None:
        raise ConfigError(
            "--live needs --model FILE: the torque model ditherlab live estimates with"
        )
    out = guard(o.out, [o.config, o.model], folder=True, force=o.force)
    if o.config is not None:
        load_params(o.config)  # a bad config is one line before any work
    model = TorqueModel.load(o.model) if o.model is not None else None
    seeds = list(range(o.seed, o.seed + o.repeats))
    with all_or_nothing(out):
        if model is None:
            dithers = DITHER_CHOICES[o.dither]
            result = compare_laws(seeds, dithers, config=o.config, progress=progress)
        else:
            result = _with_model(o, model, seeds, progress, dds)
        files = write_comparison(result, out)
    return Compared(result, files)


def _with_model(
    o: LeadthroughOptions,
    model: TorqueModel,
    seeds: list[int],
    progress: Progress | None,
    dds: Callable[..., AbstractContextManager[Any]] | None,
) -> dict[str, Any]:
    """:func:`compare_laws` driven by ``live``'s estimate with ``model``: in this process, or
    (``o.live``) over DDS and then in this process, the two compared (``closed_loop``)."""
    dithers = DITHER_CHOICES[o.dither]
    for law in LEAD_THROUGH_LAWS:  # a model of another robot is one line before any work
        link_settings(model, law, False, o.config)

    def here(law: str, dither: bool) -> AbstractContextManager[Any]:
        return nullcontext(causal_source(model, link_settings(model, law, dither, o.config)))

    if not o.live or dds is None:
        return compare_laws(seeds, dithers, config=o.config, progress=progress, sources=here)
    ns = o.namespace or f"ditherlab_leadthrough_{os.getpid()}"

    def over_dds(law: str, dither: bool) -> AbstractContextManager[Any]:
        link = link_settings(model, law, dither, o.config)
        return dds(o.model, link, namespace=ns, domain=o.domain)

    total = len(seeds) * len(dithers) * len(LEAD_THROUGH_LAWS)

    def half(offset: int) -> Progress | None:
        return None if progress is None else lambda d, _: progress(offset + d, 2 * total)

    result = compare_laws(seeds, dithers, config=o.config, progress=half(0), sources=over_dds)
    offline = compare_laws(seeds, dithers, config=o.config, progress=half(total), sources=here)
    result["closed_loop"] = closed_loop_difference(result, offline)
    return result


def compare_laws(
    seeds: Sequence[int],
    dithers: Iterable[bool] = (True, False),
    *,
    config: Any = None,
    laws: Sequence[str] = LEAD_THROUGH_LAWS,
    progress: Progress | None = None,
    sources: Callable[[str, bool], AbstractContextManager[Any]] | None = None,
) -> dict[str, Any]:
    """Simulate the lead-through with each law on the same operator pushes (same seeds) and
    measure each run with :func:`~ditherlab.analysis.lead_metrics.lead_metrics`.

    Parameters
    ----------
    seeds : simulator seeds (each seed fixes the push magnitudes and the noise)
    dithers : with and/or without dither
    config : simulator config (TOML path or dict) every run starts from; its
        ``lead_through.law`` is overridden per run
    laws : the laws compared
    progress : ``progress(done, total)`` over the runs
    sources : ``sources(law, dither)``, a context manager giving the external estimate of one
        run (:data:`ditherlab.sim.guidance.EstimateSource`; None: the controller's own eq. (3))

    Returns
    -------
    dict
        ``runs``: every run's :func:`~ditherlab.analysis.lead_metrics.lead_metrics` (without the
        per-push lists' arrays); ``means``: per ``(law, dither)`` the mean of each compared
        metric over the seeds (:func:`~ditherlab.analysis.lead_metrics.law_means`); ``paths``:
        the first seed's path per law and dither (:func:`~ditherlab.analysis.lead_metrics.path_trace`);
        ``seeds``, ``laws``, ``dithers``.
    """
    dithers = list(dithers)
    for law in laws:
        if law not in LEAD_THROUGH_LAWS:
            raise ConfigError(
                f"law {law!r} is unknown; expected one of {', '.join(LEAD_THROUGH_LAWS)}"
            )
    total = len(seeds) * len(dithers) * len(laws)
    runs: list[dict[str, Any]] = []
    paths: dict[str, Any] = {}
    for dither in dithers:
        for seed in seeds:
            for law in laws:
                with sources(law, dither) if sources else nullcontext() as estimate:
                    rec = simulate(
                        "lead-through", seed=int(seed), dither=dither, config=config, law=law,
                        estimate=estimate,
                    )  # fmt: skip
                runs.append(lead_metrics(rec))
                if seed == seeds[0]:
                    paths[f"{law}|{dither}"] = path_trace(rec)
                if progress is not None:
                    progress(len(runs), total)
    return {
        "seeds": [int(s) for s in seeds],
        "laws": list(laws),
        "dithers": dithers,
        "runs": runs,
        "means": law_means(runs, dithers, laws),
        "paths": paths,
    }
