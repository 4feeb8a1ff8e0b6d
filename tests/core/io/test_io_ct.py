import numpy as np
import pytest
import SimpleITK as sitk

from core.geometry import rotvec_to_matrix
from core.io import FileError, read_tiff_volume
from core.io.ct import inspect_dicom_folder, read_ct, split_labels
from core.render import CTVolume
from core.synthetic import bone_phantom

SPACING = 2.0


@pytest.fixture(scope="module")
def foot():
    """Talus + calcaneus phantoms (HU) on one 2 mm grid, with a label map (1 talus, 2 calcaneus)."""
    ph = {n: bone_phantom(n, spacing=SPACING).volume for n in ("talus", "calcaneus")}
    lo = np.min([v.origin for v in ph.values()], axis=0)
    hi = np.max([v.origin + (np.array(v.shape_ijk) - 1) * SPACING for v in ph.values()], axis=0)
    n = np.round((hi - lo) / SPACING).astype(int) + 1
    hu = np.full(n[::-1], -1000, np.int16)
    lab = np.zeros(n[::-1], np.int16)
    for value, (_, v) in enumerate(ph.items(), start=1):
        i0, j0, k0 = np.round((v.origin - lo) / SPACING).astype(int)
        nz, ny, nx = v.data.shape
        box = (slice(k0, k0 + nz), slice(j0, j0 + ny), slice(i0, i0 + nx))
        hu[box] = np.maximum(hu[box], v.data)
        lab[box][(v.data >= 200) & (lab[box] == 0)] = value
    D = rotvec_to_matrix([0.1, -0.2, 0.5])  # oblique, like a scan of a foot at an angle
    spacing = [SPACING, SPACING * 1.1, SPACING * 1.25]
    ct = CTVolume(hu, spacing=spacing, origin=[12.5, -40.0, 7.0], direction=D,
                  name="foot")
    return ct, lab


def _to_sitk(vol: CTVolume, data=None):
    img = sitk.GetImageFromArray(vol.data if data is None else data)
    img.SetSpacing(vol.spacing.tolist())
    img.SetOrigin(vol.origin.tolist())
    img.SetDirection(vol.direction.ravel().tolist())
    return img


def _same_geometry(a: CTVolume, b: CTVolume, atol=1e-5):
    assert a.data.shape == b.data.shape
    np.testing.assert_allclose(a.corners(), b.corners(), atol=atol)


@pytest.mark.parametrize("suffix", [".nii.gz", ".nrrd", ".mha"])
def test_itk_formats_round_trip(tmp_path, foot, suffix):
    ct, lab = foot
    p = tmp_path / f"foot{suffix}"
    sitk.WriteImage(_to_sitk(ct), str(p))
    v = read_ct(p)
    assert v.name == "foot" and v.units == "HU" and v.data.dtype == np.int16
    np.testing.assert_array_equal(v.data, ct.data)
    _same_geometry(v, ct, atol=1e-4)
    q = tmp_path / f"labels{suffix}"
    sitk.WriteImage(_to_sitk(ct, lab.astype(np.uint8)), str(q))
    L = read_ct(q, units="label")
    assert L.units == "label" and L.data.dtype == np.int32
    np.testing.assert_array_equal(L.data, lab)


def test_dicom_series_geometry_and_rescale(tmp_path, foot, dicom_writer):
    ct, _ = foot
    files = dicom_writer(tmp_path / "dcm", ct.data, spacing=ct.spacing, origin=ct.origin,
                         direction=ct.direction, slope=1.0, intercept=-1024.0)
    v = read_ct(tmp_path / "dcm")
    np.testing.assert_array_equal(v.data, ct.data)
    _same_geometry(v, ct, atol=1e-4)
    (info,) = inspect_dicom_folder(tmp_path / "dcm")
    assert info.files == tuple(files) and not info.unsorted and info.description == "CT foot"
    assert info.slice_spacing_mm == pytest.approx(ct.spacing[2])
    np.testing.assert_allclose(info.normal, ct.direction[:, 2], atol=1e-7)
    # slope 2 / intercept -1000: stored = (HU + 1000) / 2; the reader must give HU back
    even = (ct.data[:4] // 2 * 2).astype(np.int16)
    dicom_writer(tmp_path / "s2", even, slope=2.0, intercept=-1000.0)
    raw = np.frombuffer((tmp_path / "s2" / "slice_001.dcm").read_bytes()[-even[1].nbytes:], "<u2")
    np.testing.assert_array_equal(raw.reshape(even[1].shape), (even[1] + 1000) // 2)  # really stored rescaled
    np.testing.assert_array_equal(read_ct(tmp_path / "s2").data, even)
    one = read_ct(tmp_path / "s2" / "slice_002.dcm")  # a file of the series selects the series
    np.testing.assert_array_equal(one.data, even)


def test_dicom_unsorted_files_are_ordered_by_position(tmp_path, foot, dicom_writer):
    ct, _ = foot
    data = ct.data[:6]
    names = [f"IM{(5 - k) * 7 % 6:04d}" for k in range(6)]  # names and instance numbers scrambled
    dicom_writer(tmp_path / "u", data, names=names)
    (info,) = inspect_dicom_folder(tmp_path / "u")
    assert info.unsorted
    np.testing.assert_array_equal(read_ct(tmp_path / "u").data, data)


def test_dicom_problems_are_named(tmp_path, foot, dicom_writer):
    ct, _ = foot
    data = ct.data[:6]
    files = dicom_writer(tmp_path / "gap", data)
    files[3].unlink()
    msg = r"1 missing slice\(s\) between slice_002\.dcm .* and slice_004\.dcm"
    with pytest.raises(ValueError, match=msg):
        read_ct(tmp_path / "gap")
    dicom_writer(tmp_path / "mixed", data)
    dicom_writer(tmp_path / "mixed", data[:3], uid="1.2.3.999", names=["b0", "b1", "b2"], description="scout")
    msg = r"holds 2 DICOM series .*1\.2\.3\.999 \(3 files, 'scout'\).*series_uid="
    with pytest.raises(ValueError, match=msg):
        read_ct(tmp_path / "mixed")
    np.testing.assert_array_equal(read_ct(tmp_path / "mixed", series_uid="1.2.3.999").data, data[:3])
    with pytest.raises(ValueError, match=r"series_uid: '9\.9' not found"):
        read_ct(tmp_path / "mixed", series_uid="9.9")
    dicom_writer(tmp_path / "size", data)
    dicom_writer(tmp_path / "size", data[:1, :, :-2], names=["odd.dcm"], origin=(10.0, -20.0, 30.0 + 6 * 2.5))
    with pytest.raises(ValueError, match=r"odd\.dcm: mixed series .*: slice of \d+x\d+ pixels, expected"):
        read_ct(tmp_path / "size")
    dicom_writer(tmp_path / "orient", data)
    turned = rotvec_to_matrix([0, 0, 0.2])
    dicom_writer(tmp_path / "orient", data[:1], names=["turned.dcm"], direction=turned, origin=(0, 0, 99.0))
    with pytest.raises(ValueError, match=r"turned\.dcm: mixed series .*: orientation .* differs from"):
        read_ct(tmp_path / "orient")
    dicom_writer(tmp_path / "dup", data)
    dicom_writer(tmp_path / "dup", data[:1], names=["again.dcm"])
    with pytest.raises(ValueError, match="duplicate slice position"):
        read_ct(tmp_path / "dup")
    tilt = np.eye(3)
    files = dicom_writer(tmp_path / "tilt", data[:3], direction=tilt)
    dicom_writer(tmp_path / "tilt", data[:1], names=["shifted.dcm"], origin=(13.0, -20.0, 30.0 + 3 * 2.5))
    msg = r"shifted\.dcm: .* off the line along the slice normal \(gantry tilt\?\)"
    with pytest.raises(ValueError, match=msg):
        read_ct(tmp_path / "tilt")
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match="holds no DICOM images"):
        read_ct(tmp_path / "none")


def test_other_errors(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        read_ct(tmp_path / "nope.nii")
    (tmp_path / "x.vtk").write_text("?")
    with pytest.raises(ValueError, match="cannot tell the format"):
        read_ct(tmp_path / "x.vtk")
    bad = tmp_path / "bad.nii.gz"
    bad.write_bytes(b"not gzip")
    with pytest.raises(ValueError, match=r"cannot read .*bad\.nii\.gz as a volume"):
        read_ct(bad)
    rgb = tmp_path / "rgb.mha"
    sitk.WriteImage(sitk.GetImageFromArray(np.zeros((3, 4, 5, 3), np.uint8), isVector=True), str(rgb))
    with pytest.raises(ValueError, match="expected a 3-D single-channel volume, got 3-D with 3 component"):
        read_ct(rgb)
    flat = tmp_path / "flat.nrrd"
    sitk.WriteImage(sitk.GetImageFromArray(np.zeros((4, 5), np.int16)), str(flat))
    with pytest.raises(ValueError, match="got 2-D"):
        read_ct(flat)
    frac = tmp_path / "frac.mha"
    sitk.WriteImage(sitk.GetImageFromArray(np.full((2, 3, 4), 0.5, np.float32)), str(frac))
    with pytest.raises(ValueError, match="non-integer values; expected integer labels"):
        read_ct(frac, units="label")
    with pytest.raises(ValueError, match="units"):
        read_ct(frac, units="mm")


def test_split_labels(foot):
    ct, lab = foot
    subs = split_labels(ct, lab, {"talus": 1, "calcaneus": 2}, margin_mm=5.0)
    for name, value in (("talus", 1), ("calcaneus", 2)):
        sub = subs[name]
        assert sub.name == name
        # every labelled voxel is inside the crop, at the same physical place and HU
        k, j, i = np.nonzero(lab == value)
        xyz = ct.index_to_physical(np.column_stack([i, j, k]).astype(float))
        ijk = np.rint(sub.physical_to_index(xyz)).astype(int)
        nx, ny, nz = sub.shape_ijk
        assert ijk.min() >= 0 and (ijk < [nx, ny, nz]).all()
        np.testing.assert_array_equal(sub.data[ijk[:, 2], ijk[:, 1], ijk[:, 0]], ct.data[k, j, i])
        # margin: ceil(5 mm / spacing) = 3, 3, 2 voxels along i, j, k, clipped to the volume
        pad = np.array([3, 3, 2])
        lo_lab = np.array([i.min(), j.min(), k.min()])
        hi_lab = np.array([i.max(), j.max(), k.max()]) + 1
        first = np.rint(ct.physical_to_index(sub.origin)).astype(int)
        np.testing.assert_array_equal(first, np.maximum(lo_lab - pad, 0))
        np.testing.assert_array_equal(first + sub.shape_ijk, np.minimum(hi_lab + pad, ct.shape_ijk))
    auto = split_labels(ct, lab)
    assert sorted(auto) == ["label_1", "label_2"]
    clean = split_labels(ct, lab, {"talus": 1}, margin_mm=20.0, other_labels_hu=0)["talus"]
    inside = np.rint(ct.physical_to_index(clean.index_to_physical(
        np.column_stack(np.nonzero(np.ones(clean.data.shape, bool))[::-1]).astype(float)))).astype(int)
    lab_in = lab[inside[:, 2], inside[:, 1], inside[:, 0]].reshape(clean.data.shape)
    assert (lab_in == 2).any() and (clean.data[lab_in == 2] == 0).all()
    assert (clean.data[lab_in == 1] >= 200).all()


def test_split_labels_errors(foot):
    ct, lab = foot
    with pytest.raises(ValueError, match=r"label 7 .*'x'.* has no voxel"):
        split_labels(ct, lab, {"x": 7})
    other = CTVolume(lab, spacing=[1, 1, 1], name="labels")
    with pytest.raises(ValueError, match="label map 'labels' is on another voxel grid"):
        split_labels(ct, other)
    with pytest.raises(ValueError, match="expected integer labels"):
        split_labels(ct, lab.astype(float))
    with pytest.raises(ValueError, match="margin_mm"):
        split_labels(ct, lab, margin_mm=-1)
    with pytest.raises(ValueError, match="labels: expected shape"):
        split_labels(ct, lab[1:])


def test_real_wrist_tiff_volume(sample_data):
    p = sample_data / "autoscoper_wrist" / "Models" / "rad_dcm_cropped.tif"
    v = read_ct(p, voxel_size=(0.39625, 0.39625, 0.625), hu_offset=-1024)
    ref = read_tiff_volume(p, (0.39625, 0.39625, 0.625), hu_offset=-1024)
    np.testing.assert_array_equal(v.data, ref.data)
    assert v.name == "rad_dcm_cropped" and v.data.max() > 1000  # cortical bone in HU
    with pytest.raises(ValueError, match="voxel_size: required for the TIFF volume"):
        read_ct(p)


@pytest.mark.parametrize("which", [0, -1])
@pytest.mark.parametrize("keep", [10, 140, -2])
def test_damaged_first_or_last_slice_is_named_not_dropped(tmp_path, dicom_writer, which, keep):
    """A truncated end slice used to be skipped as 'not DICOM': 10 slices read as 9, origin shifted."""
    data = np.random.default_rng(0).integers(-1000, 1000, (10, 8, 8))
    files = dicom_writer(tmp_path / "s", data)
    blob = files[which].read_bytes()
    files[which].write_bytes(blob[:keep])
    with pytest.raises(FileError, match=rf"{files[which].name}: cannot be read as a DICOM slice") as err:
        read_ct(tmp_path / "s")
    assert err.value.path == files[which]
    with pytest.raises(FileError, match=files[which].name):
        inspect_dicom_folder(tmp_path / "s")


def test_damaged_extensionless_slice_and_unrelated_files(tmp_path, dicom_writer):
    data = np.random.default_rng(1).integers(-1000, 1000, (4, 8, 8))
    files = dicom_writer(tmp_path / "s", data, names=[f"IM{k:04d}" for k in range(4)])
    (tmp_path / "s" / "notes.txt").write_text("scanned on Tuesday")  # not DICOM, ignored
    (tmp_path / "s" / "DICOMDIR").write_bytes(b"\0" * 128 + b"DICM" + b"\0" * 20)  # index, ignored
    assert read_ct(tmp_path / "s").data.shape == (4, 8, 8)
    files[-1].write_bytes(files[-1].read_bytes()[:60])  # too short for the DICM preamble
    with pytest.raises(FileError, match=r"IM0003: cannot be read as a DICOM slice"):
        read_ct(tmp_path / "s")


def test_damaged_pixel_data_names_the_slice(tmp_path, dicom_writer):
    data = np.random.default_rng(2).integers(-1000, 1000, (4, 32, 32))
    files = dicom_writer(tmp_path / "s", data)
    blob = files[2].read_bytes()
    files[2].write_bytes(blob[: len(blob) - 1000])  # header intact, pixels cut
    with pytest.raises(FileError, match=files[2].name):
        read_ct(tmp_path / "s")
