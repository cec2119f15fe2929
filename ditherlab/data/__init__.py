"""The data types that cross every boundary: the :class:`~ditherlab.data.recording.Recording`
(one time-indexed table plus metadata; the contract is ``docs/recording-format.md``), the
:class:`~ditherlab.data.torque_model.TorqueModel` (bands per regime, prior, effects, history; a
TOML file) and the :class:`~ditherlab.data.estimates.Estimates` (what ``replay`` writes and
``report`` and ``view`` read).

Imports :mod:`ditherlab.core` and :mod:`ditherlab.robot` only.
"""
