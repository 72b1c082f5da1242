"""surfnorm.io.threef2n: the 3F2N dataset's layout, its depth and parameter files."""

import gzip

import numpy as np
import pytest

from surfnorm import DataFileError
from surfnorm.io.threef2n import find_frames, read_depth_bin, read_frame, read_params, sample_root


def test_shipped_sample():
    names = find_frames(sample_root())
    assert names == ["Easy/android/000001", "Medium/Trex/000001", "Hard/batman/000001"]
    f = read_frame(sample_root(), names[0])
    assert f.depth.shape == (480, 640) and f.depth.dtype == np.float32
    assert f.normals.shape == (480, 640, 3)
    np.testing.assert_array_equal(f.mask, f.depth != 1.0)
    # ground truth is unit length on the object and faces the camera
    n = f.normals[f.mask]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1, atol=1e-5)
    assert np.mean(n[:, 2] < 0) > 0.99
    # params.txt is 1-based: 1400 1380 320 260 -> cx = 319, cy = 259
    assert (f.K.fx, f.K.fy, f.K.cx, f.K.cy) == (1400, 1380, 319, 259)


def test_matches_uncompressed_original(shared_sample):
    """The 12 compressed frames of tests/data decompress to the dataset's files (SHA-256 of each .bin as shipped),
    and the package's shipped frame is the same depth."""
    import hashlib

    sums = dict(line.split()[::-1] for line in (shared_sample / "SHA256SUMS").read_text().splitlines())
    assert len(sums) == 12 and len(find_frames(shared_sample)) == 12
    for path, digest in sums.items():
        assert hashlib.sha256(gzip.decompress((shared_sample / (path + ".gz")).read_bytes())).hexdigest() == digest, (
            path
        )
    f = read_frame(sample_root(), "Easy/android/000001")
    np.testing.assert_array_equal(f.depth, read_frame(shared_sample, "Easy/android/000001").depth)


def test_bad_files(tmp_path):
    (tmp_path / "short.bin").write_bytes(b"\0" * 100)
    with pytest.raises(DataFileError, match=r"short.bin: expected 1228800 bytes of float32 depth \(480x640\), got 100"):
        read_depth_bin(tmp_path / "short.bin")
    (tmp_path / "bad.bin.gz").write_bytes(b"not gzip")
    with pytest.raises(DataFileError, match=r"bad.bin.gz: truncated or corrupt gzip stream"):
        read_depth_bin(tmp_path / "bad.bin.gz")
    with pytest.raises(DataFileError, match=r"missing.bin: cannot read depth file"):
        read_depth_bin(tmp_path / "missing.bin")
    (tmp_path / "params.txt").write_text("fx fy")
    with pytest.raises(DataFileError, match=r"params.txt: expected 'fx fy u0 v0 count' numbers"):
        read_params(tmp_path / "params.txt")
    good = tmp_path / "ok.bin.gz"
    good.write_bytes(gzip.compress(np.ones((480, 640), np.float32).tobytes()))
    assert read_depth_bin(good).sum() == 480 * 640
