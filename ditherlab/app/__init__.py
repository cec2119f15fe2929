"""The workflows behind the commands: each reads its input files, calls the analyses, and writes
its outputs through the output guard. The command line (:mod:`ditherlab.cli`) and the package's
front door (:mod:`ditherlab`) call these.
"""
