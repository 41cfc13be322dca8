"""The one place Qt is imported: pyqtgraph on PyQt6, the binding the monitor extra
installs and the tests run on (pyqtgraph would otherwise take whichever binding it
finds first)."""
import os

os.environ.setdefault("PYQTGRAPH_QT_LIB", "PyQt6")

import pyqtgraph as pg  # noqa: E402  (after the binding is chosen)
from pyqtgraph.Qt import QtCore, QtGui, QtWidgets  # noqa: E402

__all__ = ["pg", "QtCore", "QtGui", "QtWidgets"]
