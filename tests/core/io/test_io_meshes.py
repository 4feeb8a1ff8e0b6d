import base64
import itertools
import lzma
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.geometry import make_rigid, rotvec_to_matrix
from core.io.meshes import Mesh, read_mesh, write_mesh
from core.synthetic import box_mesh, icosphere

HALF = (10.0, 15.0, 7.5)  # box half extents, mm -> volume 8 * 10 * 15 * 7.5 = 9000 mm^3


@pytest.fixture(scope="module")
def box():
    V, F = box_mesh(HALF, center=(1.0, -2.0, 30.0))
    return Mesh(V, F, "box")


def _same_surface(a: Mesh, b: Mesh):
    """Same triangles (as sets of vertex positions), whatever the vertex numbering."""
    def tris(m):
        t = np.round(m.vertices[m.faces], 5)
        return sorted(map(tuple, np.sort(t.reshape(len(t), 3, 3).tolist(), axis=1).reshape(len(t), 9)))
    assert tris(a) == tris(b)


FORMATS = [(".stl", True), (".stl", False), (".ply", True), (".ply", False), (".obj", False), (".vtp", True),
           (".vtp", False)]


@pytest.mark.parametrize(("suffix", "binary"), FORMATS)
def test_round_trip_formats(tmp_path, box, suffix, binary):
    p = tmp_path / f"bone{suffix}"
    write_mesh(box, p, binary=binary)
    m = read_mesh(p)
    assert m.name == "bone" and m.n_faces == 12 and m.n_vertices == 8
    assert m.volume() == pytest.approx(9000.0, rel=1e-6)  # outward orientation kept
    assert m.area() == pytest.approx(8 * (10 * 15 + 10 * 7.5 + 15 * 7.5), rel=1e-6)
    _same_surface(m, box)


def test_sphere_and_transform(tmp_path):
    V, F = icosphere(radius=12.0, subdivisions=3, center=(5, 6, 7))
    s = Mesh(V, F)
    write_mesh(s, tmp_path / "s.stl")
    m = read_mesh(tmp_path / "s.stl")
    assert m.n_faces == 1280 and abs(m.volume() - 4 / 3 * np.pi * 12**3) / (4 / 3 * np.pi * 12**3) < 0.02
    T = make_rigid(rotvec_to_matrix([0.3, -0.1, 0.2]), [10, 20, 30])
    moved = m.transformed(T)
    np.testing.assert_allclose(moved.vertices.mean(axis=0), T[:3, :3] @ m.vertices.mean(axis=0) + T[:3, 3])
    assert moved.volume() == pytest.approx(m.volume())


# ------------------------------------------------------------------ VTP encodings written by hand
def _vtp(points_xml, polys_xml, *, attrs="", appended=""):
    return (f'<?xml version="1.0"?><VTKFile type="PolyData" version="1.0" {attrs}><PolyData>'
            f'<Piece NumberOfPoints="4" NumberOfPolys="2"><Points>{points_xml}</Points>'
            f"<Polys>{polys_xml}</Polys></Piece></PolyData>{appended}</VTKFile>")


QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)


def _blk(arr, *, header="<u4", compress=None, separate=False):
    data = arr.tobytes()
    if compress is None:
        h = np.array([len(data)], header).tobytes()
        if separate:
            return base64.b64encode(h).decode() + base64.b64encode(data).decode()
        return base64.b64encode(h + data).decode()
    blob = compress(data)
    h = np.array([1, len(data), len(data), len(blob)], header).tobytes()
    return base64.b64encode(h).decode() + base64.b64encode(blob).decode()


@pytest.mark.parametrize(
    ("kw", "attrs"),
    [
        ({}, 'byte_order="LittleEndian"'),
        ({"separate": True}, 'byte_order="LittleEndian"'),
        ({"header": "<u8"}, 'byte_order="LittleEndian" header_type="UInt64"'),
        ({"compress": zlib.compress}, 'byte_order="LittleEndian" compressor="vtkZLibDataCompressor"'),
        ({"compress": lzma.compress}, 'byte_order="LittleEndian" compressor="vtkLZMADataCompressor"'),
    ],
)
def test_vtp_inline_binary_variants(tmp_path, kw, attrs):
    pts = _blk(QUAD.astype("<f4"), **kw)
    conn = _blk(np.array([0, 1, 2, 3], "<i4"), **kw)  # one quad -> two triangles
    offs = _blk(np.array([4], "<i4"), **kw)
    text = _vtp(f'<DataArray type="Float32" NumberOfComponents="3" format="binary">{pts}</DataArray>',
                f'<DataArray type="Int32" Name="connectivity" format="binary">{conn}</DataArray>'
                f'<DataArray type="Int32" Name="offsets" format="binary">{offs}</DataArray>', attrs=attrs)
    p = tmp_path / "q.vtp"
    p.write_text(text)
    m = read_mesh(p)
    np.testing.assert_array_equal(m.vertices, QUAD)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])


def test_vtp_appended_raw_base64_bigendian_strips(tmp_path):
    pts = QUAD.astype(">f8").tobytes()
    conn = np.array([0, 1, 3, 2], ">i8").tobytes()  # a strip of two triangles
    offs = np.array([4], ">i8").tobytes()
    blocks = [np.array([len(b)], ">u4").tobytes() + b for b in (pts, conn, offs)]
    o = np.cumsum([0] + [len(b) for b in blocks])
    arrays = (
        f'<DataArray type="Float64" NumberOfComponents="3" format="appended" offset="{o[0]}"/>',
        f'<DataArray type="Int64" Name="connectivity" format="appended" offset="{o[1]}"/>'
        f'<DataArray type="Int64" Name="offsets" format="appended" offset="{o[2]}"/>',
    )
    head = _vtp(arrays[0], "", attrs='byte_order="BigEndian"')
    head = head.replace("<Polys></Polys>", f"<Strips>{arrays[1]}</Strips>")
    raw = head.replace("</VTKFile>", '<AppendedData encoding="raw">_').encode() + b"".join(blocks)
    raw += b"</AppendedData></VTKFile>"
    p = tmp_path / "raw.vtp"
    p.write_bytes(raw)
    m = read_mesh(p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 3], [3, 1, 2]])  # 2nd strip triangle flipped
    assert m.area() == pytest.approx(1.0)
    b64 = [base64.b64encode(b).decode() for b in blocks]
    o = np.cumsum([0] + [len(b) for b in b64])
    text = _vtp(f'<DataArray type="Float64" NumberOfComponents="3" format="appended" offset="{o[0]}"/>',
                f'<DataArray type="Int64" Name="connectivity" format="appended" offset="{o[1]}"/>'
                f'<DataArray type="Int64" Name="offsets" format="appended" offset="{o[2]}"/>',
                attrs='byte_order="BigEndian"',
                appended=f'<AppendedData encoding="base64">_{"".join(b64)}</AppendedData>')
    (tmp_path / "b64.vtp").write_text(text)
    m2 = read_mesh(tmp_path / "b64.vtp")
    np.testing.assert_array_equal(m2.faces, [[0, 1, 3], [0, 3, 2]])  # one polygon, fan-triangulated


@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("trunc.stl", b"\x00" * 80 + (2).to_bytes(4, "little") + b"\x00" * 60, "neither a binary STL"),
        ("bad.stl", b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 1 2\n",
         r"line 4: expected 'vertex x y z'"),
        ("two.stl", b"solid x\nvertex 0 0 0\nvertex 1 0 0\n", "expected 3 per facet"),
        ("x.vtp", b"<VTKFile type='PolyData'><PolyData>", "not well-formed XML"),
        ("u.vtp", b"<VTKFile type='UnstructuredGrid'/>", 'expected <VTKFile type="PolyData">'),
        ("e.vtp", b"<VTKFile type='PolyData'><PolyData/></VTKFile>", "no PolyData Piece"),
        ("c.vtp", b"<VTKFile type='PolyData' compressor='vtkFooCompressor'><PolyData/></VTKFile>",
         "compressor 'vtkFooCompressor' is not supported"),
        ("g.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nend_header\n1 2\n", r"cannot read as PLY"),
        ("n.obj", b"v 0 0 0\nv 1 0 0\n", "no triangles or polygons"),
    ],
)
def test_bad_mesh_files(tmp_path, name, content, match):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(ValueError, match=match):
        read_mesh(p)


def test_vtp_index_errors(tmp_path):
    arr = ('<DataArray type="Float32" NumberOfComponents="3" format="ascii">'
           "0 0 0 1 0 0 1 1 0 0 1 0</DataArray>")
    for conn, offs, match in [("0 1 9", "3", "outside 0..3"), ("0 1 2", "4", "offsets do not index")]:
        p = tmp_path / "i.vtp"
        polys = (f'<DataArray type="Int32" Name="connectivity" format="ascii">{conn}</DataArray>'
                 f'<DataArray type="Int32" Name="offsets" format="ascii">{offs}</DataArray>')
        p.write_text(_vtp(arr, polys))
        with pytest.raises(ValueError, match=match):
            read_mesh(p)
    with pytest.raises(ValueError, match="faces: indices must lie in"):
        Mesh(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ValueError, match="not a mesh file"):
        read_mesh(tmp_path / "x.off")
    with pytest.raises(ValueError, match="no such mesh file"):
        read_mesh(tmp_path / "x.stl")


_n = itertools.count()


@settings(
    max_examples=200,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(data=st.data())
def test_fuzz_damaged_mesh_files(tmp_path_factory, box, data):
    folder = tmp_path_factory.getbasetemp() / "meshfuzz"
    folder.mkdir(exist_ok=True)
    suffix, binary = data.draw(st.sampled_from([(s, b) for s in (".stl", ".vtp") for b in (True, False)]))
    src = folder / f"src{suffix}{int(binary)}{suffix}"
    if not src.exists():
        write_mesh(box, src, binary=binary)
    blob = bytearray(src.read_bytes())
    for _ in range(data.draw(st.integers(1, 5))):
        i = data.draw(st.integers(0, 1 << 20)) % len(blob)
        if data.draw(st.booleans()):
            blob[i] = data.draw(st.integers(0, 255))
        else:
            del blob[i:]
            break
    p = folder / f"m{next(_n)}{suffix}"
    p.write_bytes(bytes(blob))
    try:
        read_mesh(p)
    except ValueError:
        pass
