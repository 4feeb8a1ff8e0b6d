import numpy as np
import pytest
import SimpleITK as sitk

from core.io.ct import split_labels
from core.render import CTVolume
from core.study import Study, StudyError
from core.synthetic import bone_phantom


def test_bone_volumes_from_a_labelled_ct(tmp_path):
    ct = bone_phantom("talus", spacing=2.0).volume
    lab = np.zeros(ct.data.shape, np.int16)
    bone = ct.data >= 200
    half = ct.data.shape[2] // 2
    lab[:, :, :half][bone[:, :, :half]] = 1  # two "bones": the two halves of the talus
    lab[:, :, half:][bone[:, :, half:]] = 2
    for name, arr in (("ct.nii.gz", ct.data), ("labels.nii.gz", lab)):
        img = sitk.GetImageFromArray(arr)
        img.SetSpacing(ct.spacing.tolist())
        img.SetOrigin(ct.origin.tolist())
        sitk.WriteImage(img, str(tmp_path / name))
    with Study.create(tmp_path / "st") as st:
        st.add_volume("foot", tmp_path / "ct.nii.gz", labels=tmp_path / "labels.nii.gz")
        st.add_bone("medial", volume="foot", label=1, margin_mm=4.0)
        st.add_bone("whole", volume="foot")
        with pytest.raises(StudyError, match="no volume named 'x'"):
            st.add_bone("b", volume="x")
        with pytest.raises(ValueError, match="voxel_size_mm: required for the TIFF volume"):
            (tmp_path / "v.tif").write_bytes(b"x")
            st.add_volume("t", tmp_path / "v.tif")
    with Study.open(tmp_path / "st") as st:
        medial = st.bone_volume("medial")
        ref = split_labels(CTVolume(ct.data, spacing=ct.spacing, origin=ct.origin), lab, {"medial": 1},
                           margin_mm=4.0)["medial"]
        np.testing.assert_array_equal(medial.data, ref.data)
        np.testing.assert_allclose(medial.origin, ref.origin, atol=1e-5)
        assert medial.data.shape[2] < ct.data.shape[2]
        np.testing.assert_array_equal(st.bone_volume("whole").data, ct.data)
        with pytest.raises(StudyError, match="no bone named 'tibia'"):
            st.bone_volume("tibia")
