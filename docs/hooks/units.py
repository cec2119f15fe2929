"""mkdocs hook: units in brackets are text, not cross-references.

ditherlab's docstrings give every quantity its unit in brackets, time first:
``duration: t[-1] - t[0] [s]``. Where a bracketed unit follows another bracket, Markdown reads the
two as a reference link (``[0] [s]``), and mkdocs-autorefs then warns that it cannot find the
target ``s`` — which fails ``mkdocs build --strict``. This hook drops exactly those warnings:
an unresolved target made only of units. Any other unresolved cross-reference still warns.
"""

from __future__ import annotations

import logging
import re

#: the units docstrings write in brackets (SI, arm side), and a few counts
UNITS = set(
    "s ms Hz m mm kg N N·m Nm rad deg rad/s rad/s² rad/s^2 m/s m/s³ N·m/rad N·m·s/rad kg·m² °C "
    "degC 1/s 1 - samples bytes MB N/s N·m/A A %".split()
)
_TARGET = re.compile(r"Could not find cross-reference target '([^']*)'")
_LOGGERS = (
    "mkdocs.plugins.mkdocs_autorefs._internal.plugin",
    "mkdocs.plugins.mkdocs_autorefs.plugin",
)


def _is_units(target: str) -> bool:
    parts = [p for p in re.split(r"[,\s]+", target.strip()) if p]
    return bool(parts) and all(p in UNITS for p in parts)


class _UnitsAreText(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        m = _TARGET.search(record.getMessage())
        return not (m and _is_units(m.group(1)))


_FILTER = _UnitsAreText()


def on_config(config):
    for name in _LOGGERS:
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
    return config
