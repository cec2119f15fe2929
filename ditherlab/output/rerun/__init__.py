"""Outputs for the eye: the Rerun view (:mod:`ditherlab.output.rerun.rerun_log`, its entry points, built on
:mod:`~ditherlab.output.rerun.inputs`, :mod:`~ditherlab.output.rerun.columns`, :mod:`~ditherlab.output.rerun.robot3d`,
:mod:`~ditherlab.output.rerun.panels`, :mod:`~ditherlab.output.rerun.events`, :mod:`~ditherlab.output.rerun.rrd`) and its
layout (:mod:`ditherlab.output.rerun.blueprint`); the report's PNG figures (:mod:`ditherlab.output.figures`);
the diagnosis report and its reader (:mod:`ditherlab.output.diagnosis_report`)."""

from __future__ import annotations
