"""The workflows behind the commands, one module per command (``info``, ``convert``,
``simulate``, ``identify``, ``replay``, ``report``, ``diagnose``, ``view``, ``robot``, ``fleet``,
``sweep``, ``leadthrough``; and ``demo``): each has a frozen options dataclass, ``run(options)``
and a result that says itself as text (``text()``) and as JSON (``to_dict()``). A workflow reads
its input files, calls the analyses and writes its outputs after the output guard
(:mod:`ditherlab.app.workflow`). The command line (:mod:`ditherlab.cli`) and the package's front
door (:mod:`ditherlab`) call these.
"""
