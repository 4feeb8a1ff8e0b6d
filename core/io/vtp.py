"""VTK XML PolyData (``.vtp``) surfaces, parsed and written without VTK.

Format (VTK "XML File Formats")::

    <VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt32"
             [compressor="vtkZLibDataCompressor"]>
      <PolyData><Piece NumberOfPoints="N" NumberOfPolys="M" ...>
        <Points><DataArray type="Float32" NumberOfComponents="3" format="..."/></Points>
        <Polys> <DataArray Name="connectivity"/> <DataArray Name="offsets"/> </Polys>
        <Strips> (same, triangle strips) </Strips>
      </Piece></PolyData>
      [<AppendedData encoding="base64|raw">_...</AppendedData>]
    </VTKFile>

``format`` is ``ascii`` (whitespace-separated numbers), ``binary`` (inline base64) or
``appended`` (at byte ``offset`` after the ``_`` of ``AppendedData``). Binary data is a header
of ``header_type`` integers followed by the bytes: uncompressed ``[nbytes]`` + data (base64 as
one block or header and data as two); compressed ``[nblocks, block_size, last_block_size,
compressed sizes...]`` + the compressed blocks (header and blocks base64-encoded separately).
``offsets`` hold the end of each polygon in ``connectivity``. Polygons are fan-triangulated and
strips split into triangles (alternate ones flipped to keep the winding); vertices and lines
are ignored.
"""

from __future__ import annotations

import base64
import binascii
import lzma
import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np

from .errors import reads

__all__ = ["read_vtp", "write_vtp"]

_TYPES = {
    "Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
    "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8",
}
_COMPRESSORS = {"vtkZLibDataCompressor": zlib.decompress, "vtkLZMADataCompressor": lzma.decompress}


def _b64chars(nbytes: int) -> int:
    return -(-nbytes // 3) * 4


class _Decoder:
    def __init__(self, path: Path, root: ET.Element, appended: bytes | None):
        self.path = path
        order = root.get("byte_order", "LittleEndian")
        if order not in ("LittleEndian", "BigEndian"):
            raise ValueError(f"{path}: byte_order {order!r}; expected LittleEndian or BigEndian")
        self.endian = "<" if order == "LittleEndian" else ">"
        htype = root.get("header_type", "UInt32")
        if htype not in ("UInt32", "UInt64"):
            raise ValueError(f"{path}: header_type {htype!r}; expected UInt32 or UInt64")
        self.header = np.dtype(self.endian + _TYPES[htype])
        comp = root.get("compressor")
        if comp is not None and comp not in _COMPRESSORS:
            raise ValueError(f"{path}: compressor {comp!r} is not supported (zlib or lzma)")
        self.decompress = _COMPRESSORS.get(comp) if comp else None
        self.appended = appended
        self.appended_raw = False

    def array(self, el: ET.Element, what: str) -> np.ndarray:
        t = el.get("type")
        if t not in _TYPES:
            raise ValueError(f"{self.path}: {what}: DataArray type {t!r} is not supported")
        dtype = np.dtype(self.endian + _TYPES[t])
        fmt = el.get("format", "ascii")
        try:
            if fmt == "ascii":
                return np.array((el.text or "").split(), dtype=float).astype(dtype)
            if fmt == "binary":
                return self._binary((el.text or "").strip().encode(), dtype, b64=True)
            if fmt == "appended":
                if self.appended is None:
                    raise ValueError("format 'appended' but the file has no AppendedData")
                off = int(el.get("offset", "0"))
                if not 0 <= off <= len(self.appended):
                    raise ValueError(f"offset {off} outside the appended data")
                return self._binary(self.appended[off:], dtype, b64=not self.appended_raw)
        except (ValueError, TypeError, binascii.Error, zlib.error, lzma.LZMAError, OverflowError) as exc:
            raise ValueError(f"{self.path}: {what}: cannot decode {fmt} DataArray ({exc})") from None
        raise ValueError(f"{self.path}: {what}: DataArray format {fmt!r}; expected ascii, binary or appended")

    def _take(self, data: bytes, nbytes: int, b64: bool, pos: int) -> tuple[bytes, int]:
        """``nbytes`` decoded bytes starting at ``pos`` (chars if base64); new position."""
        if not b64:
            chunk = data[pos : pos + nbytes]
            if len(chunk) < nbytes:
                raise ValueError("data shorter than announced")
            return chunk, pos + nbytes
        n = _b64chars(nbytes)
        chunk = base64.b64decode(data[pos : pos + n], validate=True)[:nbytes]
        if len(chunk) < nbytes:
            raise ValueError("data shorter than announced")
        return chunk, pos + n

    def _binary(self, data: bytes, dtype: np.dtype, *, b64: bool) -> np.ndarray:
        h = self.header.itemsize
        if b64:
            data = re.sub(rb"\s+", b"", data)
        head, _ = self._take(data, h, b64, 0)
        first = int(np.frombuffer(head, self.header)[0])
        if self.decompress is None:
            if b64 and b"=" in data[: _b64chars(h)]:  # header base64-encoded on its own
                body, _ = self._take(data, first, True, _b64chars(h))
            else:  # header and data in one block
                whole, _ = self._take(data, h + first, b64, 0)
                body = whole[h:]
        else:
            if first > 1 << 24:
                raise ValueError(f"implausible block count {first}")
            head, pos = self._take(data, h * (3 + first), b64, 0)
            sizes = np.frombuffer(head, self.header)[3:].astype(np.int64)
            blob, _ = self._take(data, int(sizes.sum()), b64, pos)
            ends = np.cumsum(sizes)
            body = b"".join(self.decompress(blob[e - s : e]) for s, e in zip(sizes, ends, strict=True))
        if len(body) % dtype.itemsize:
            raise ValueError(f"{len(body)} bytes is not a whole number of {dtype} values")
        return np.frombuffer(body, dtype)


def _split_raw(path: Path, raw: bytes) -> tuple[bytes, bytes | None]:
    """Separate raw appended binary data (not valid XML) from the XML text."""
    m = re.search(rb"<AppendedData[^>]*encoding=\"raw\"[^>]*>\s*_", raw)
    if not m:
        return raw, None
    end = raw.rfind(b"</AppendedData>")
    if end < m.end():
        raise ValueError(f"{path}: AppendedData is not closed")
    xml = raw[: m.end() - 1] + raw[end:]
    return xml, raw[m.end() : end]


def _triangles(path: Path, conn: np.ndarray, offs: np.ndarray, n_points: int, strips: bool) -> np.ndarray:
    conn = conn.astype(np.int64)
    offs = offs.astype(np.int64)
    starts = np.concatenate([[0], offs[:-1]])
    if len(offs) and (offs[-1] != len(conn) or np.any(np.diff(offs) < 0) or offs[0] < 0):
        raise ValueError(f"{path}: offsets do not index the connectivity array ({len(conn)} entries)")
    if len(conn) and (conn.min() < 0 or conn.max() >= n_points):
        raise ValueError(f"{path}: connectivity refers to points outside 0..{n_points - 1}")
    tris = []
    for s, e in zip(starts, offs, strict=True):
        cell = conn[s:e]
        if len(cell) < 3:
            continue
        if strips:
            for k in range(len(cell) - 2):
                a, b, c = cell[k : k + 3]
                tris.append((a, b, c) if k % 2 == 0 else (b, a, c))
        else:
            tris += [(cell[0], cell[k], cell[k + 1]) for k in range(1, len(cell) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


@reads("a VTK XML PolyData (.vtp) surface")
def read_vtp(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a ``.vtp`` surface: ``(vertices (N, 3) float64, triangles (M, 3) int64)``."""
    path = Path(path)
    raw = path.read_bytes()
    xml, appended_raw = _split_raw(path, raw)
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not well-formed XML ({exc})") from None
    if root.tag != "VTKFile" or root.get("type") != "PolyData":
        raise ValueError(
            f"{path}: expected <VTKFile type=\"PolyData\">, got <{root.tag} type={root.get('type')!r}>"
        )
    app_el = root.find("AppendedData")
    appended = None
    if appended_raw is not None:
        appended = appended_raw
    elif app_el is not None:
        if app_el.get("encoding", "raw") != "base64":
            raise ValueError(
                f"{path}: AppendedData encoding {app_el.get('encoding')!r}; expected base64 or raw"
            )
        text = (app_el.text or "").strip()
        if not text.startswith("_"):
            raise ValueError(f"{path}: AppendedData must start with '_'")
        appended = text[1:].encode()
    dec = _Decoder(path, root, appended)
    dec.appended_raw = appended_raw is not None
    pieces = root.findall("PolyData/Piece")
    if not pieces:
        raise ValueError(f"{path}: no PolyData Piece")
    verts, faces, base = [], [], 0
    for i, piece in enumerate(pieces):
        pts_el = piece.find("Points/DataArray")
        if pts_el is None:
            raise ValueError(f"{path}: Piece {i} has no Points DataArray")
        pts = dec.array(pts_el, f"Piece {i} Points").astype(np.float64)
        n_pts = int(piece.get("NumberOfPoints", len(pts) // 3))
        if pts_el.get("NumberOfComponents", "3") != "3" or pts.size != 3 * n_pts:
            raise ValueError(f"{path}: Piece {i} Points: expected {n_pts} x 3 values, got {pts.size}")
        pts = pts.reshape(-1, 3)
        tris = []
        for tag, strips in (("Polys", False), ("Strips", True)):
            el = piece.find(tag)
            if el is None:
                continue
            arrays = {a.get("Name"): a for a in el.findall("DataArray")}
            if "connectivity" not in arrays or "offsets" not in arrays:
                raise ValueError(f"{path}: Piece {i} {tag}: expected connectivity and offsets arrays")
            conn = dec.array(arrays["connectivity"], f"Piece {i} {tag} connectivity")
            offs = dec.array(arrays["offsets"], f"Piece {i} {tag} offsets")
            tris.append(_triangles(path, conn, offs, len(pts), strips))
        verts.append(pts)
        faces += [t + base for t in tris]
        base += len(pts)
    F = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    if len(F) == 0:
        raise ValueError(f"{path}: no polygons or triangle strips (a surface mesh was expected)")
    return np.concatenate(verts), F


def _encode(arr: np.ndarray, binary: bool, compress: bool) -> str:
    if not binary:
        return " ".join(repr(x.item()) for x in arr.ravel())
    data = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<")).tobytes()
    if not compress:
        return base64.b64encode(np.array([len(data)], "<u4").tobytes() + data).decode()
    blob = zlib.compress(data)
    header = np.array([1, len(data), len(data), len(blob)], "<u4").tobytes()
    return base64.b64encode(header).decode() + base64.b64encode(blob).decode()


def write_vtp(
    path, vertices: np.ndarray, faces: np.ndarray, *, binary: bool = True, compress: bool = False
) -> None:
    """Write triangles as a single-piece ``.vtp`` (ascii or inline base64, optionally zlib) to ``path``."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    fmt = "binary" if binary else "ascii"
    comp = ' compressor="vtkZLibDataCompressor"' if (binary and compress) else ""

    def da(arr, typ, name, ncomp=1):
        nm = f' Name="{name}"' if name else ""
        return (f'<DataArray type="{typ}"{nm} NumberOfComponents="{ncomp}" format="{fmt}">'
                f"{_encode(arr, binary, compress)}</DataArray>")

    text = (
        f'<?xml version="1.0"?>\n<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
        f'header_type="UInt32"{comp}>\n<PolyData>\n'
        f'<Piece NumberOfPoints="{len(V)}" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" '
        f'NumberOfPolys="{len(F)}">\n'
        f"<Points>{da(V, 'Float64', 'Points', 3)}</Points>\n"
        f"<Polys>{da(F.ravel(), 'Int64', 'connectivity')}"
        f"{da(np.arange(1, len(F) + 1, dtype=np.int64) * 3, 'Int64', 'offsets')}</Polys>\n"
        "</Piece>\n</PolyData>\n</VTKFile>\n"
    )
    Path(path).write_text(text, encoding="utf-8")
