"""The 3D attitude view: a board model turned by the estimate, in the earth's east, north
and up axes, drawn with OpenGL (pyqtgraph.opengl, which needs PyOpenGL).

The board is a flat box in its own frame: x to the right (red), y forward (green, the
edge the arrow marks), z up out of the top face (blue). Its transform is the
sensor-to-earth rotation R of the estimate, vertex_earth = R vertex_board, with R from the
Euler angles in imulink's convention, R = Rz(-heading) Rx(pitch) Ry(roll) (heading
clockwise from north; imulink.analysis.attitude.quat_to_euler is its inverse). The earth axes are
fixed: east (x), north (y), up (z).

Where no OpenGL context can be made (Qt's offscreen platform, a remote display without
GLX) :func:`opengl_problem` says why, and the window shows the artificial horizon alone.
"""
from __future__ import annotations

import math

import numpy as np

from imulink.monitor.qt import QtGui

#: The board's half sizes in its frame (x, y, z), scene units: a GY-86 carrier's 2:3 outline.
BOARD_HALF_SIZE = (1.0, 1.5, 0.08)
AXIS_LENGTH = 2.4


def opengl_problem() -> str | None:
    """None when the 3D view can be drawn, else why not (one line)."""
    try:
        import OpenGL  # noqa: F401 - pyqtgraph.opengl needs it
        import pyqtgraph.opengl  # noqa: F401
    except ImportError as exc:
        return f"no OpenGL bindings ({exc.name}: pip install 'imulink[monitor]')"
    from imulink.monitor.qt import QtWidgets

    if QtWidgets.QApplication.platformName() == "offscreen":
        return "Qt's offscreen platform has no OpenGL"
    context = QtGui.QOpenGLContext()
    if not context.create():
        return "no OpenGL context on this display"
    return None


def rotation_matrix(roll_deg: float, pitch_deg: float, heading_deg: float) -> np.ndarray:
    """The sensor-to-earth rotation (3x3, ENU) of Euler angles in imulink's convention."""
    r, p, h = (math.radians(v) for v in (roll_deg, pitch_deg, heading_deg))
    rz = np.array([[math.cos(-h), -math.sin(-h), 0.0], [math.sin(-h), math.cos(-h), 0.0], [0.0, 0.0, 1.0]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), -math.sin(p)], [0.0, math.sin(p), math.cos(p)]])
    ry = np.array([[math.cos(r), 0.0, math.sin(r)], [0.0, 1.0, 0.0], [-math.sin(r), 0.0, math.cos(r)]])
    return rz @ rx @ ry


def _box_mesh():
    """Vertices (8, 3) and triangles (12, 3) of the board, with a colour per triangle:
    the top face green, the bottom dark, the forward edge (+y) red, the others grey."""
    hx, hy, hz = BOARD_HALF_SIZE
    vertices = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)])
    index = {(sx, sy, sz): 4 * sx + 2 * sy + sz for sx in (0, 1) for sy in (0, 1) for sz in (0, 1)}
    faces, colors = [], []
    quads = {  # corner indices of each face, counter-clockwise seen from outside
        "top": [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], "bottom": [(0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)],
        "front": [(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)], "back": [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)],
        "right": [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)], "left": [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)]}
    shades = {"top": (0.15, 0.55, 0.25, 1.0), "bottom": (0.08, 0.25, 0.12, 1.0), "front": (0.85, 0.15, 0.1, 1.0)}
    for name, corners in quads.items():
        a, b, c, d = (index[corner] for corner in corners)
        faces += [(a, b, c), (a, c, d)]
        colors += [shades.get(name, (0.55, 0.55, 0.55, 1.0))] * 2
    return vertices, np.array(faces), np.array(colors)


def _matrix4(rotation: np.ndarray) -> QtGui.QMatrix4x4:
    m = np.eye(4)
    m[:3, :3] = rotation
    return QtGui.QMatrix4x4(*m.ravel().tolist())  # row by row


def make_view():
    """A pyqtgraph GLViewWidget with the earth axes, a ground grid and the board; call
    :func:`set_attitude` on it. Only after :func:`opengl_problem` said None."""
    import pyqtgraph.opengl as gl

    class BoardView(gl.GLViewWidget):
        def __init__(self):
            super().__init__()
            self.setBackgroundColor((245, 245, 245))
            self.setCameraPosition(distance=9.0, elevation=22.0, azimuth=-115.0)
            self.setMinimumSize(200, 160)
            grid = gl.GLGridItem(color=(0, 0, 0, 40))
            grid.setSize(8, 8)
            grid.translate(0, 0, -2.0)
            self.addItem(grid)
            for axis, (name, color) in enumerate((("E", (0.8, 0.1, 0.1, 1)), ("N", (0.1, 0.6, 0.1, 1)),
                                                  ("U", (0.1, 0.3, 0.9, 1)))):
                end = np.zeros(3)
                end[axis] = AXIS_LENGTH
                # 'translucent': the default additive blending would wash the lines out on a light background
                self.addItem(gl.GLLinePlotItem(pos=np.array([np.zeros(3), end]), color=color, width=2,
                                               glOptions="translucent"))
                self.addItem(gl.GLTextItem(pos=end * 1.1, text=name, color=QtGui.QColor(0, 0, 0)))
            vertices, faces, colors = _box_mesh()
            self.board = gl.GLMeshItem(vertexes=vertices, faces=faces, faceColors=colors, smooth=False,
                                       drawEdges=True, edgeColor=(0, 0, 0, 1))
            self.addItem(self.board)
            for axis, color in enumerate(((1, 0.3, 0.3, 1), (0.3, 0.9, 0.3, 1), (0.4, 0.6, 1, 1))):
                end = np.zeros(3)
                end[axis] = 1.8
                line = gl.GLLinePlotItem(pos=np.array([np.zeros(3), end]), color=color, width=3,
                                         glOptions="translucent")
                line.setParentItem(self.board)  # turns with the board
            self.rotation = np.eye(3)

        def set_attitude(self, roll: float, pitch: float, heading: float) -> None:
            if all(math.isfinite(v) for v in (roll, pitch, heading)):
                self.rotation = rotation_matrix(roll, pitch, heading)
                self.board.setTransform(_matrix4(self.rotation))

    return BoardView()
