"""Visual review: Rerun logging (:mod:`ditherlab.viz.rerun_log`) and its layout
(:mod:`ditherlab.viz.blueprint`)."""

from __future__ import annotations
