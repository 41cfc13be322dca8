"""The attitude panel: an artificial horizon with a roll scale and a heading tape, drawn
with QPainter (no OpenGL needed).

Conventions are imulink's (README): roll about the board's forward (y) axis, positive
when its right side (x) goes down; pitch about x, positive nose (y) up; heading
clockwise from north. So the horizon turns by -roll on screen and moves down as the
nose comes up, as in an aircraft's attitude indicator.
"""
from __future__ import annotations

import math

from imulink.monitor.qt import QtCore, QtGui, QtWidgets

_SKY, _GROUND = QtGui.QColor(58, 130, 201), QtGui.QColor(132, 94, 56)
_MARK = QtGui.QColor(255, 204, 0)
_CARDINALS = {0: "N", 90: "E", 180: "S", 270: "W"}


class HorizonWidget(QtWidgets.QWidget):
    """Shows (roll, pitch, heading) in degrees, set with :meth:`set_attitude`."""

    #: Degrees of pitch per horizon half-height, and degrees of heading across the tape.
    PITCH_RANGE_DEG = 40.0
    TAPE_SPAN_DEG = 120.0

    def __init__(self, parent=None):
        super().__init__(parent)
        self.roll = self.pitch = self.heading = 0.0
        self.setMinimumSize(220, 220)

    def set_attitude(self, roll: float, pitch: float, heading: float) -> None:
        if all(math.isfinite(v) for v in (roll, pitch, heading)):
            self.roll, self.pitch, self.heading = float(roll), float(pitch), float(heading) % 360.0
            self.update()

    def sizeHint(self) -> QtCore.QSize:
        return QtCore.QSize(260, 280)

    def paintEvent(self, event) -> None:
        painter = QtGui.QPainter(self)
        painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
        tape_height = 36
        horizon = QtCore.QRectF(0, 0, self.width(), self.height() - tape_height)
        self._draw_horizon(painter, horizon)
        self._draw_tape(painter, QtCore.QRectF(0, horizon.bottom(), self.width(), tape_height))
        painter.end()

    def _draw_horizon(self, painter: QtGui.QPainter, rect: QtCore.QRectF) -> None:
        painter.save()
        painter.setClipRect(rect)
        center = rect.center()
        radius = min(rect.width(), rect.height()) / 2.0
        per_deg = radius / self.PITCH_RANGE_DEG
        big = math.hypot(rect.width(), rect.height()) + abs(self.pitch) * per_deg  # covers the view at any angle
        painter.translate(center)
        painter.rotate(-self.roll)
        painter.translate(0, self.pitch * per_deg)
        painter.fillRect(QtCore.QRectF(-big, -big, 2 * big, big), _SKY)
        painter.fillRect(QtCore.QRectF(-big, 0, 2 * big, big), _GROUND)
        painter.setPen(QtGui.QPen(QtCore.Qt.GlobalColor.white, 2))
        painter.drawLine(QtCore.QPointF(-big, 0), QtCore.QPointF(big, 0))
        painter.setPen(QtGui.QPen(QtCore.Qt.GlobalColor.white, 1))
        font = painter.font()
        font.setPointSizeF(7.5)
        painter.setFont(font)
        for step in range(-90, 91, 10):  # the pitch ladder (the rungs in view)
            if step == 0 or abs(step - self.pitch) > self.PITCH_RANGE_DEG * 1.5:
                continue
            y = -step * per_deg
            half = radius * (0.28 if step % 20 == 0 else 0.16)
            painter.drawLine(QtCore.QPointF(-half, y), QtCore.QPointF(half, y))
            if step % 20 == 0:
                painter.drawText(QtCore.QPointF(half + 4, y + 4), f"{step}")
        painter.restore()
        painter.save()
        painter.translate(center)
        self._draw_roll_scale(painter, radius)
        painter.setPen(QtGui.QPen(_MARK, 3))  # the board, fixed in the middle
        painter.drawLine(QtCore.QPointF(-radius * 0.45, 0), QtCore.QPointF(-radius * 0.12, 0))
        painter.drawLine(QtCore.QPointF(radius * 0.12, 0), QtCore.QPointF(radius * 0.45, 0))
        painter.drawEllipse(QtCore.QPointF(0, 0), 3, 3)
        painter.setPen(QtCore.Qt.GlobalColor.white)
        # across the panel's width, not the dial's: in a short panel the text is wider than the dial
        painter.drawText(QtCore.QRectF(-rect.width() / 2, radius - 22, rect.width(), 20),
                         QtCore.Qt.AlignmentFlag.AlignCenter, f"roll {self.roll:+.1f}°  pitch {self.pitch:+.1f}°")
        painter.restore()

    def _draw_roll_scale(self, painter: QtGui.QPainter, radius: float) -> None:
        r = radius * 0.85
        painter.setPen(QtGui.QPen(QtCore.Qt.GlobalColor.white, 1.5))
        for mark in (-60, -45, -30, -20, -10, 0, 10, 20, 30, 45, 60):
            a = math.radians(mark - 90)
            inner = r - (10 if mark % 30 == 0 else 6)
            painter.drawLine(QtCore.QPointF(r * math.cos(a), r * math.sin(a)),
                             QtCore.QPointF(inner * math.cos(a), inner * math.sin(a)))
        a = math.radians(-self.roll - 90)  # the pointer turns with the horizon
        tip = QtCore.QPointF((r - 12) * math.cos(a), (r - 12) * math.sin(a))
        side = math.radians(4)
        left = QtCore.QPointF((r - 24) * math.cos(a - side), (r - 24) * math.sin(a - side))
        right = QtCore.QPointF((r - 24) * math.cos(a + side), (r - 24) * math.sin(a + side))
        painter.setBrush(_MARK)
        painter.setPen(QtCore.Qt.PenStyle.NoPen)
        painter.drawPolygon(QtGui.QPolygonF([tip, left, right]))

    def _draw_tape(self, painter: QtGui.QPainter, rect: QtCore.QRectF) -> None:
        painter.save()
        painter.setClipRect(rect)
        painter.fillRect(rect, QtGui.QColor(30, 30, 30))
        per_deg = rect.width() / self.TAPE_SPAN_DEG
        cx = rect.center().x()
        painter.setPen(QtGui.QPen(QtCore.Qt.GlobalColor.white, 1))
        first = int(math.floor((self.heading - self.TAPE_SPAN_DEG / 2) / 5.0)) * 5
        for mark in range(first, int(self.heading + self.TAPE_SPAN_DEG / 2) + 5, 5):
            x = cx + (mark - self.heading) * per_deg
            length = 10 if mark % 10 == 0 else 5
            painter.drawLine(QtCore.QPointF(x, rect.top()), QtCore.QPointF(x, rect.top() + length))
            if mark % 30 == 0:
                label = _CARDINALS.get(mark % 360, f"{mark % 360:d}")
                painter.drawText(QtCore.QRectF(x - 20, rect.top() + 10, 40, 14), QtCore.Qt.AlignmentFlag.AlignCenter,
                                 label)
        box = QtCore.QRectF(cx - 30, rect.bottom() - 14, 60, 14)
        painter.fillRect(box, QtCore.Qt.GlobalColor.black)
        painter.setPen(_MARK)
        painter.drawRect(box)
        painter.drawText(box, QtCore.Qt.AlignmentFlag.AlignCenter, f"{self.heading:05.1f}°")
        painter.drawLine(QtCore.QPointF(cx, rect.top()), QtCore.QPointF(cx, rect.top() + 14))
        painter.restore()
