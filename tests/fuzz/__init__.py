"""A fuzz suite for ditherlab's promise on bad input.

Every case runs one CLI command (info, convert, identify, replay, diagnose, report, view --save)
on one input and checks the promise of ``errors.py`` and of ``docs/recording-format.md`` ("Bad
input"): exit 0, or exit 2 with exactly one line ``error: ...`` on stderr (progress lines of a
non-TTY run aside), no traceback, no hang (60 s), the input's bytes unchanged, and no output (nor
temporary file) left behind by a failure.

Inputs (:mod:`tests.fuzz.inputs`): recordings drawn by hypothesis strategies (valid, and invalid
on purpose: wrong dtypes, NaN/inf, non-monotonic or duplicated ``t``, missing or duplicated
columns, one or two rows, huge gaps, constant signals, numbers stored as text), written as
Parquet or CSV; and mutations (byte flips, truncation, text edits) of real files: the Parquet,
CSV, MCAP and ROS 2 bags (MCAP and SQLite storage) that ``ditherlab simulate`` and ``convert``
make, the hopper's Parquet logs, the UR10e's CSV logs and rosbag2's own MCAP files.

- ``make fuzz`` (``python -m tests.fuzz --cases 1000``): the campaign, one subprocess per case,
  reproducible from ``--seed``; prints a table of cases per command and input kind and the
  findings by class, and writes the findings (with a command that reproduces each) to
  ``--findings``.
- ``make test`` runs ``tests/test_fuzz.py``: the same cases on a small budget.
"""
