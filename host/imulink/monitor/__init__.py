"""`imulink monitor`: a live window on a board, an emulated board or a recording.

Qt and pyqtgraph are an optional extra (``pip install 'imulink[monitor]'``) and are
imported only by :mod:`imulink.monitor.window` and :mod:`imulink.monitor.horizon`; the
data side (:mod:`.sources`, :mod:`.check`, :mod:`.ring`) needs neither. docs/monitor.md
describes the window.
"""
from __future__ import annotations

import importlib.util

INSTALL_HINT = "pip install 'imulink[monitor]'"


def missing_dependencies() -> str | None:
    """None when the window can be shown, else one line naming what is missing and how to install it."""
    missing = [name for name in ("PyQt6", "pyqtgraph") if importlib.util.find_spec(name) is None]
    if not missing:
        return None
    return f"imulink monitor needs {' and '.join(missing)}: {INSTALL_HINT}"
