"""The plots dock's export (:meth:`app.plots.PlotsDock.export`): every page to PNG, SVG or one
PDF, as vector output (the screen's pixmap caches switched off while writing), each file written
atomically."""

from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets


def export_pages(path: str, canvases: dict, shown: str, drawn, show_page) -> list:
    """Write the pages ``canvases`` (page name -> its ``pg.GraphicsLayoutWidget``) by the file's
    suffix: ``.pdf`` one page per tab in one file; ``.png`` / ``.svg`` the page ``shown`` to
    ``path`` and every other page to ``<stem>-<page><suffix>`` beside it. ``drawn(page)`` shows a
    page with its curves drawn and returns its canvas; ``show_page(shown)`` restores the page
    shown at the end. Every file is written to a temporary name and renamed into place. Returns
    the paths written."""
    from core.io.atomic import atomic_path, output_file

    p = output_file(path, (".png", ".svg", ".pdf"), "a .png, .svg or .pdf file")
    suffix = p.suffix.lower()
    written = []
    cache = QtWidgets.QGraphicsItem.CacheMode
    cached = [item for canvas in canvases.values() for item in canvas.scene().items()
              if item.cacheMode() != cache.NoCache]
    for item in cached:  # vector output: lines and text, not the screen's pixmaps
        item.setCacheMode(cache.NoCache)
    try:
        if suffix == ".pdf":
            with atomic_path(p) as tmp:
                writer = QtGui.QPdfWriter(str(tmp))
                writer.setPageSize(QtGui.QPageSize(QtGui.QPageSize.PageSizeId.A4))
                writer.setPageOrientation(QtGui.QPageLayout.Orientation.Landscape)
                writer.setResolution(150)
                painter = QtGui.QPainter(writer)
                try:
                    for k, page in enumerate(canvases):
                        if k:
                            writer.newPage()
                        scene = drawn(page).scene()
                        rect, src = painter.viewport(), scene.sceneRect()
                        scale = min(rect.width() / src.width(), rect.height() / src.height())
                        scene.render(painter, QtCore.QRectF(0, 0, src.width() * scale,
                                                            src.height() * scale), src)
                finally:
                    painter.end()
            written.append(p)
        else:
            from pyqtgraph.exporters import ImageExporter

            for page in [shown, *[q for q in canvases if q != shown]]:
                dest = p if page == shown else p.with_name(f"{p.stem}-{page.replace(' ', '-')}{suffix}")
                canvas = drawn(page)
                with atomic_path(dest) as tmp:
                    if suffix == ".png":
                        ex = ImageExporter(canvas.scene())
                        ex.parameters()["width"] = max(int(canvas.width()), 1200)
                        ex.export(str(tmp))
                    else:  # Qt's own SVG writer: pyqtgraph's SVGExporter fails on filled items
                        _write_svg(canvas.scene(), tmp)
                written.append(dest)
    finally:
        for item in cached:
            item.setCacheMode(cache.DeviceCoordinateCache)
        show_page(shown)
    for w in written:
        if not w.is_file() or w.stat().st_size == 0:
            raise OSError(f"{w}: the plot export wrote nothing")
    return written


def _write_svg(scene, path) -> None:
    """Render a graphics scene to an SVG file with QtSvg (vector paths and text)."""
    from PySide6.QtSvg import QSvgGenerator

    src = scene.sceneRect()
    gen = QSvgGenerator()
    gen.setFileName(str(path))
    gen.setSize(QtCore.QSize(int(src.width()), int(src.height())))
    gen.setViewBox(QtCore.QRectF(0, 0, src.width(), src.height()))
    gen.setTitle("Talus plot")
    painter = QtGui.QPainter(gen)
    try:
        scene.render(painter, QtCore.QRectF(0, 0, src.width(), src.height()), src)
    finally:
        painter.end()
