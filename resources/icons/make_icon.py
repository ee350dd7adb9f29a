"""Draws resources/icons/motion-composer.png (run once; the PNG is committed).

A dark rounded square with two stick figures: the capture (blue) and the character it is
put onto (orange), mid-stride.
"""
from __future__ import annotations

import sys
from pathlib import Path

from PySide6 import QtCore, QtGui

SIZE = 256


def figure(p: QtGui.QPainter, color: str, x: float, scale: float) -> None:
    pen = QtGui.QPen(QtGui.QColor(color), 14 * scale, QtCore.Qt.PenStyle.SolidLine,
                     QtCore.Qt.PenCapStyle.RoundCap, QtCore.Qt.PenJoinStyle.RoundJoin)
    p.setPen(pen)
    s = scale
    pts = {"head": (x, 62 * s), "neck": (x, 92 * s), "hips": (x + 4 * s, 150 * s),
           "lh": (x - 30 * s, 128 * s), "rh": (x + 34 * s, 112 * s),
           "lk": (x - 14 * s, 188 * s), "lf": (x - 34 * s, 222 * s),
           "rk": (x + 24 * s, 186 * s), "rf": (x + 30 * s, 226 * s)}
    for a, b in (("neck", "hips"), ("neck", "lh"), ("neck", "rh"), ("hips", "lk"),
                 ("lk", "lf"), ("hips", "rk"), ("rk", "rf")):
        p.drawLine(QtCore.QPointF(*pts[a]), QtCore.QPointF(*pts[b]))
    p.setBrush(QtGui.QColor(color))
    p.drawEllipse(QtCore.QPointF(*pts["head"]), 16 * s, 16 * s)


def main(out: str) -> None:
    app = QtGui.QGuiApplication.instance() or QtGui.QGuiApplication(sys.argv[:1])  # noqa: F841
    img = QtGui.QImage(SIZE, SIZE, QtGui.QImage.Format.Format_ARGB32)
    img.fill(QtCore.Qt.GlobalColor.transparent)
    p = QtGui.QPainter(img)
    p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
    p.setBrush(QtGui.QColor("#26282c"))
    p.setPen(QtCore.Qt.PenStyle.NoPen)
    p.drawRoundedRect(QtCore.QRectF(8, 8, SIZE - 16, SIZE - 16), 40, 40)
    figure(p, "#739ed9", 82, 0.9)
    figure(p, "#f29940", 168, 1.0)
    p.end()
    img.save(out)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).with_name("motion-composer.png")))
