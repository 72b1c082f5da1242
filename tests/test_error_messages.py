"""Error paths that the module tests do not reach: each message is asserted here."""

import cv2
import numpy as np
import pytest

import surfnorm
from surfnorm import DataFileError, InputError, Intrinsics
from surfnorm.batch import plan_tasks
from surfnorm.io.depth import read_depth, read_mask
from surfnorm.io.intrinsics import read_intrinsics
from surfnorm.io.normals import read_normals
from surfnorm.io.threef2n import read_frame, read_normal_png, read_params, sample_root
from surfnorm.methods import Method, register


def test_intrinsics_need_real_numbers():
    with pytest.raises(InputError, match=r"intrinsics.fx: expected a real number, got str 'a'"):
        Intrinsics("a", 1, 1, 1)


def test_registry_refuses_bad_names_and_categories():
    with pytest.raises(ValueError, match=r"method name 'x\+mnr' may not contain '\+mnr'"):
        register(Method("x+mnr", "averaging", "ref", "summary", lambda *a, **k: None))
    with pytest.raises(ValueError, match=r"category of 'x': expected one of"):
        register(Method("x", "magic", "ref", "summary", lambda *a, **k: None))


def test_one_intrinsics_per_frame():
    with pytest.raises(InputError, match=r"K: expected one intrinsics for all 2 frames or one per frame, got 3"):
        surfnorm.estimate(np.ones((2, 5, 5)), [Intrinsics(1, 1, 1, 1)] * 3)


def test_depth_and_mask_files(tmp_path):
    np.save(tmp_path / "d.npy", np.zeros((4, 4, 2)))
    with pytest.raises(DataFileError, match=r"d.npy: expected a 2-D depth image, got an array of shape \(4, 4, 2\)"):
        read_depth(tmp_path / "d.npy")
    with pytest.raises(DataFileError, match=r"missing.png: cannot read mask file"):
        read_mask(tmp_path / "missing.png")
    np.save(tmp_path / "m.npy", np.zeros((4, 4, 2), bool))
    with pytest.raises(DataFileError, match=r"m.npy: expected a 2-D mask, got an array of shape \(4, 4, 2\)"):
        read_mask(tmp_path / "m.npy")
    np.savez(tmp_path / "two.npz", a=np.ones((2, 2)), b=np.ones((2, 2)))
    with pytest.raises(DataFileError, match=r"two.npz: expected an array named 'mask' or a single array in the .npz "
                                            r"archive, got 2 arrays \(a, b\)"):
        read_mask(tmp_path / "two.npz")
    (tmp_path / "cut.npy").write_bytes((tmp_path / "m.npy").read_bytes()[:60])
    with pytest.raises(DataFileError, match=r"cut.npy: cannot read as NumPy .npy mask \(truncated or corrupt"):
        read_mask(tmp_path / "cut.npy")
    with pytest.raises(DataFileError, match=r"missing.npy: cannot read mask file"):
        read_mask(tmp_path / "missing.npy")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG not an image")
    with pytest.raises(DataFileError, match=r"bad.png: cannot decode as an image \(empty, truncated or corrupt\)"):
        read_mask(tmp_path / "bad.png")
    np.savez(tmp_path / "named.npz", other=np.zeros((2, 2)), mask=np.eye(2))
    np.testing.assert_array_equal(read_mask(tmp_path / "named.npz"), np.eye(2, dtype=bool))


def test_normal_files(tmp_path):
    (tmp_path / "n.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(DataFileError, match=r"n.png: cannot decode as PNG \(empty, truncated or corrupt\)"):
        read_normals(tmp_path / "n.png")


def test_3f2n_layout_errors(tmp_path):
    with pytest.raises(DataFileError, match=r"params.txt: cannot read 3F2N params.txt"):
        read_params(tmp_path / "params.txt")
    with pytest.raises(DataFileError, match=r"gt.png: cannot read as an image \(missing, truncated or not a PNG\)"):
        read_normal_png(tmp_path / "gt.png")
    cv2.imwrite(str(tmp_path / "gt8.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DataFileError, match=r"gt8.png: expected a 16-bit RGB PNG, got shape \(4, 4, 3\) dtype uint8"):
        read_normal_png(tmp_path / "gt8.png")
    # a frame whose ground truth has another size than its depth
    src = sample_root() / "Easy" / "android"
    obj = tmp_path / "Easy" / "android"
    (obj / "depth").mkdir(parents=True)
    (obj / "normal").mkdir()
    (obj / "depth" / "000001.bin.gz").write_bytes((src / "depth" / "000001.bin.gz").read_bytes())
    (obj / "params.txt").write_text((src / "params.txt").read_text())
    cv2.imwrite(str(obj / "normal" / "000001.png"), np.zeros((4, 4, 3), np.uint16))
    with pytest.raises(DataFileError, match=r"expected \(480, 640\) pixels to match depth, got \(4, 4\)"):
        read_frame(tmp_path, "Easy/android/000001")


def test_intrinsics_files(tmp_path):
    with pytest.raises(DataFileError, match=r"expected an intrinsics file, got a directory"):
        read_intrinsics(tmp_path)
    (tmp_path / "k.yaml").write_text("fx: [1, 2\n")
    with pytest.raises(DataFileError, match=r"k.yaml: cannot parse as YAML"):
        read_intrinsics(tmp_path / "k.yaml")


def test_convert_inputs_and_output_dir(tmp_path):
    with pytest.raises(InputError, match=r"inputs: expected a path, a glob pattern or a list of files, got int"):
        plan_tasks(123, tmp_path / "out")
    (tmp_path / "blocker").write_text("a file")
    np.save(tmp_path / "d.npy", np.ones((8, 8), np.float32))
    with pytest.raises(InputError, match=r"output_dir: (cannot create the folder|expected a folder)"):
        surfnorm.convert([tmp_path / "d.npy"], tmp_path / "blocker" / "out", intrinsics=Intrinsics(5, 5, 3.5, 3.5))


def test_torch_intrinsics_tensors():
    torch = pytest.importorskip("torch")
    import surfnorm.torch as st

    depth = torch.ones(5, 5)
    with pytest.raises(InputError, match=r"K: expected shape \(3, 3\) or \(1, 3, 3\) for 1 frame\(s\)"):
        st.estimate(depth, torch.eye(2))
    with pytest.raises(InputError, match=r"K: expected a real \(3, 3\) or \(1, 3, 3\) intrinsic matrix"):
        st.estimate(depth, torch.eye(3, dtype=torch.complex64))
