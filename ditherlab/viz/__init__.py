"""Outputs for the eye: the Rerun view (:mod:`ditherlab.viz.rerun_log`, its entry points, built on
:mod:`~ditherlab.viz.inputs`, :mod:`~ditherlab.viz.stream`, :mod:`~ditherlab.viz.robot3d`,
:mod:`~ditherlab.viz.panels`, :mod:`~ditherlab.viz.events`, :mod:`~ditherlab.viz.rrd`) and its
layout (:mod:`ditherlab.viz.blueprint`); the report's PNG figures (:mod:`ditherlab.viz.figures`);
the diagnosis report and its reader (:mod:`ditherlab.viz.diagnosis`)."""

from __future__ import annotations
