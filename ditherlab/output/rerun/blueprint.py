"""The Rerun layout (blueprint) that ``ditherlab view`` opens on.

Left: the robot in 3D with the force arrows and intervals, the event log below it. Right, one
tab each: forces per axis (the paper's Figs. 6 and 7), torques per joint with the friction band,
dither and extraction per joint (Figs. 4 and 5), residuals per model version, information.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from ditherlab.core.names import FORCE_AXES


def make_blueprint(
    n_joints: int,
    variants: Sequence[str] = (),
    *,
    has_wrench: bool = True,
) -> rrb.Blueprint:
    """Build the default layout for a recording of ``n_joints`` joints.

    Parameters
    ----------
    n_joints : number of robot joints (one plot per joint in each joint tab)
    variants : estimator variants present (only used to name the force tab)
    has_wrench : whether the recording has the F/T sensor columns

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    joints = range(1, n_joints + 1)
    torque = _torque_tab(joints)
    dither = _dither_tab(joints)
    residual = _residual_tab(joints)
    forces = _forces_tab(variants)
    info = rrb.Tabs(
        rrb.TextDocumentView(origin="info/recording", name="Recording"),
        rrb.TextDocumentView(origin="info/diagnosis", name="Diagnosis"),
        rrb.TextDocumentView(origin="info/history", name="Model history"),
        rrb.TextDocumentView(origin="info/model", name="Model"),
        name="Info",
    )
    tabs = (
        [forces, torque, dither, residual, info]
        if has_wrench or variants
        else [torque, dither, residual, info]
    )
    left = rrb.Vertical(
        rrb.Spatial3DView(origin="robot", name="Robot and forces"),
        rrb.TextLogView(origin="/", contents=["/events/**", "/diagnosis/**"], name="Events"),
        row_shares=[3, 2],
    )
    return rrb.Blueprint(
        rrb.Horizontal(left, rrb.Tabs(*tabs), column_shares=[2, 3]),
        rrb.TimePanel(state="expanded"),
        collapse_panels=False,
    )


def _torque_tab(joints: range) -> rrb.Grid:
    """Per joint: tau - gravity against J^T F of the sensor with the bands, and the logged
    torque."""
    return rrb.Grid(
        *[
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=f"joints/{j}",
                    contents=["$origin/tau_bar", "$origin/band/**"],
                    name=f"joint {j}: tau - gravity, J^T F (sensor), bands [N·m]",
                ),
                rrb.TimeSeriesView(
                    origin=f"joints/{j}/tau", name=f"joint {j}: logged torque [N·m]"
                ),
                row_shares=[2, 1],
            )
            for j in joints
        ],
        name="Torques",
    )


def _dither_tab(joints: range) -> rrb.Grid:
    """Per joint: the extraction and the centre (Figs. 4, 5), the amplitude (Fig. 5), the
    extracted signal against J^T F and the bands (Fig. 4)."""
    return rrb.Grid(
        *[
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=f"joints/{j}",
                    contents=[
                        "$origin/tau",
                        "$origin/extract/**",
                        "$origin/dither/centre/**",
                        "$origin/dither/ffw",
                    ],
                    name=f"joint {j}: tau, upper/lower/signal, centre (Figs. 4, 5) [N·m]",
                ),
                rrb.TimeSeriesView(
                    origin=f"joints/{j}/dither/amplitude",
                    contents=["$origin/**", "/events/dither_flag"],
                    name=f"joint {j}: dither amplitude, measured and reference (Fig. 5) [N·m]",
                ),
                rrb.TimeSeriesView(
                    origin=f"joints/{j}",
                    contents=["$origin/fig4/**", "$origin/tau_bar", "$origin/band/**"],
                    name=f"joint {j}: extracted signal - gravity, J^T F, bands (Fig. 4) [N·m]",
                ),
            )
            for j in joints
        ],
        name="Dither (Figs. 4, 5)",
    )


def _residual_tab(joints: range) -> rrb.Vertical:
    """Per joint the residual of every model version, and its RMS per version."""
    return rrb.Vertical(
        rrb.Grid(
            *[
                rrb.TimeSeriesView(
                    origin=f"joints/{j}/residual",
                    name=f"joint {j}: residual per model version [N·m]",
                )
                for j in joints
            ]
        ),
        rrb.Horizontal(
            *[
                rrb.BarChartView(
                    origin=f"history/torque_rms/{j}", name=f"joint {j}: RMS per version [N·m]"
                )
                for j in joints
            ]
        ),
        row_shares=[3, 1],
        name="Residuals",
    )


def _forces_tab(variants: Sequence[str]) -> rrb.Vertical:
    """Per force axis the sensor and the estimates (Figs. 6, 7)."""
    return rrb.Vertical(
        *[
            rrb.TimeSeriesView(origin=f"force/{a}", name=f"f_{a} [N]: sensor and estimates")
            for a in FORCE_AXES
        ],
        name="Forces (Figs. 6, 7)" + (f": {', '.join(variants)}" if variants else ""),
    )
