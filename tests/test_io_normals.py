"""Normal-map files: NPY, 16-bit PNG (3F2N encoding), 8-bit pictures; round trips, determinism, atomicity."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from surfnorm.errors import DataFileError, InputError
from surfnorm.io.normals import decode_png, encode_png16, read_normals, write_normals
from surfnorm.io.threef2n import read_normal_png, sample_root


def random_normals(h=20, w=30, seed=0):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(h, w, 3))
    n[..., 2] = -np.abs(n[..., 2])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n = n.astype(np.float32)
    n[0, 0] = 0.0  # missing
    n[1, 1] = np.nan  # missing
    return n


def missing(n):
    return np.zeros(n.shape[:2], bool) | np.isnan(n).any(-1) | (n == 0).all(-1)


def test_npy_round_trip_is_exact(tmp_path):
    n = random_normals()
    write_normals(tmp_path / "n.npy", n)
    np.testing.assert_array_equal(read_normals(tmp_path / "n.npy"), n)


def test_png16_round_trip_within_quantisation(tmp_path):
    n = random_normals()
    write_normals(tmp_path / "n.png", n, fmt="png16")
    back = read_normals(tmp_path / "n.png", fill=np.nan)
    gone = missing(n)
    assert np.isnan(back[gone]).all()
    # 1.5e-5 per component quantisation, renormalised: a few 1e-5 at most
    assert np.abs(back[~gone] - n[~gone]).max() < 4e-5
    img = cv2.imread(str(tmp_path / "n.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (20, 30, 3)
    # RGB order in the file, 3F2N encoding png = (1 - n) * 65535 / 2
    np.testing.assert_array_equal(
        img[5, 7, ::-1], np.rint((1 - n[5, 7].astype(np.float64)) * 65535 / 2).astype(np.uint16)
    )
    assert (img[0, 0] == 65535).all()


@pytest.mark.parametrize("colouring, formula", [("3f2n", lambda n: (1 - n) / 2), ("opengl", lambda n: (n + 1) / 2)])
def test_png8_picture_colourings(tmp_path, colouring, formula):
    n = random_normals()
    write_normals(tmp_path / "p.png", n, fmt="png8", colouring=colouring)
    img = cv2.imread(str(tmp_path / "p.png"), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    assert img.dtype == np.uint8
    np.testing.assert_array_equal(img[3, 4], np.rint(formula(n[3, 4]) * 255).astype(np.uint8))
    assert (img[0, 0] == 255).all() and (img[1, 1] == 255).all()
    back = read_normals(tmp_path / "p.png", colouring=colouring)
    gone = missing(n)
    assert (back[gone] == 0).all()
    angle = np.degrees(np.arccos(np.clip(np.sum(back[~gone] * n[~gone], -1), -1, 1)))
    assert angle.max() < 1.0  # 8 bits: a picture, under a degree off


def test_writes_are_deterministic_and_leave_no_temporaries(tmp_path):
    n = random_normals()
    for fmt, suffix in (("npy", ".npy"), ("png16", ".png"), ("png8", ".png")):
        a = write_normals(tmp_path / f"a_{fmt}{suffix}", n, fmt=fmt).read_bytes()
        b = write_normals(tmp_path / f"b_{fmt}{suffix}", n.copy(), fmt=fmt).read_bytes()
        assert a == b
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    import surfnorm.io.normals as mod

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mod.np, "save", boom)
    with pytest.raises(DataFileError, match=r"cannot write .*n\.npy \(No space left on device\)"):
        write_normals(tmp_path / "n.npy", random_normals())
    assert list(tmp_path.iterdir()) == []


def test_reads_3f2n_ground_truth_like_the_dataset_reader():
    path = sample_root() / "Easy" / "android" / "normal" / "000001.png"
    ours = read_normals(path)
    theirs = read_normal_png(path)
    fg = ~(ours == 0).all(-1)
    assert fg.mean() > 0.1
    np.testing.assert_allclose(ours[fg], theirs[fg], atol=1e-6)
    # the white background decodes to length sqrt(3): missing
    assert (ours[0, 0] == 0).all()


def test_encode_decode_helpers():
    n = random_normals(4, 5)
    back = decode_png(encode_png16(n), fill=7.0)
    assert (back[0, 0] == 7).all()
    with pytest.raises(InputError, match=r"colouring: expected one of '3f2n', 'opengl', got 'hsv'"):
        decode_png(encode_png16(n), colouring="hsv")


def test_bad_normal_files_and_arguments(tmp_path):
    with pytest.raises(InputError, match=r"fmt: expected one of 'npy', 'png16', 'png8', got 'exr'"):
        write_normals(tmp_path / "n.exr", random_normals(), fmt="exr")
    with pytest.raises(InputError, match=r"normals: expected a float array of shape \(H, W, 3\), got shape \(4, 4\)"):
        write_normals(tmp_path / "n.npy", np.zeros((4, 4)))
    (tmp_path / "t.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00")
    with pytest.raises(DataFileError, match=r"t.png: cannot decode as PNG"):
        read_normals(tmp_path / "t.png")
    np.save(tmp_path / "flat.npy", np.zeros((4, 4)))
    with pytest.raises(
        DataFileError, match=r"flat.npy: expected a float array of shape \(H, W, 3\), got shape \(4, 4\)"
    ):
        read_normals(tmp_path / "flat.npy")
    (tmp_path / "c.npy").write_bytes(b"junk")
    with pytest.raises(DataFileError, match=r"c.npy: cannot read as a NumPy normal map"):
        read_normals(tmp_path / "c.npy")
    cv2.imwrite(str(tmp_path / "grey.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(
        DataFileError, match=r"grey.png: expected an 8- or 16-bit RGB PNG normal map, got shape \(4, 4\)"
    ):
        read_normals(tmp_path / "grey.png")
    with pytest.raises(DataFileError, match=r"n.tif: unknown normal file type '.tif'"):
        (tmp_path / "n.tif").write_bytes(b"x")
        read_normals(tmp_path / "n.tif")
    with pytest.raises(DataFileError, match=r"none.npy: cannot read normal file \(No such file or directory\)"):
        read_normals(tmp_path / "none.npy")
