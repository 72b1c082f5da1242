"""Depth files as sensors and their tools write them: OpenEXR, 16-bit PGM, PFM, Kinect v1 disparity.

Files are written here by the OpenEXR package or byte by byte from the
netpbm specification, and read back with surfnorm.io.read_depth; the real
frames of ../shared/data/sensor-sample are compared with their depth.npy
when that folder exists.
"""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

import surfnorm
from surfnorm.errors import DataFileError, InputError, MissingDependencyError
from surfnorm.io.depth import KINECT_V1_NYU, kinect_disparity_to_depth, read_depth, sun_rgbd_to_depth

SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample"


def sensor_frame(name: str) -> Path:
    folder = SENSOR_SAMPLE / name
    if not (folder / "depth.npy").is_file():
        pytest.skip(f"the sensor sample frame {name} is not at {folder}")
    return folder


# ---------------------------------------------------------------------------- OpenEXR


def write_exr(path: Path, channels: dict, parts=None) -> Path:
    OpenEXR = pytest.importorskip("OpenEXR")
    if parts is not None:
        OpenEXR.File([OpenEXR.Part({"name": name}, chans) for name, chans in parts.items()]).write(str(path))
    else:
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, channels).write(str(path))
    return path


def depth_with_holes(dtype=np.float32, shape=(24, 32), seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.3, 4.0, shape).astype(dtype)
    z[rng.random(shape) < 0.1] = np.nan  # RealSense tools write holes as NaN
    return z


class TestExr:
    def test_float32_z_channel_round_trip_keeps_nan_holes(self, tmp_path):
        z = depth_with_holes(np.float32)
        out = read_depth(write_exr(tmp_path / "d.exr", {"Z": z}))
        assert out.dtype == np.float32 and out.shape == z.shape
        np.testing.assert_array_equal(out, z)  # NaN at the same places, every other value exact
        assert np.isnan(out).sum() == np.isnan(z).sum() > 0

    def test_float16_depth_channel_is_exact(self, tmp_path):
        z = depth_with_holes(np.float16, seed=1)
        out = read_depth(write_exr(tmp_path / "d.exr", {"depth": z}))
        np.testing.assert_array_equal(out, z.astype(np.float32))

    def test_depth_copied_into_rgb_reads_r(self, tmp_path):
        """ClearGrasp's RealSense frames hold the same metres in R, G and B."""
        z = depth_with_holes(np.float16, seed=2)
        out = read_depth(write_exr(tmp_path / "d.exr", {"R": z, "G": z.copy(), "B": z.copy()}))
        np.testing.assert_array_equal(out, z.astype(np.float32))

    def test_blender_layer_names_pick_the_depth_pass(self, tmp_path):
        z = depth_with_holes(np.float32, seed=3)
        colour = np.random.default_rng(4).random(z.shape).astype(np.float32)
        chans = {
            "ViewLayer.Combined.R": colour,
            "ViewLayer.Combined.G": colour * 0.5,
            "ViewLayer.Combined.B": colour * 0.25,
            "ViewLayer.Combined.A": np.ones_like(colour),
            "ViewLayer.Depth.Z": z,
        }
        np.testing.assert_array_equal(read_depth(write_exr(tmp_path / "d.exr", chans)), z)

    def test_luminance_channel(self, tmp_path):
        z = depth_with_holes(np.float32, seed=5)
        chroma = np.zeros_like(z)
        np.testing.assert_array_equal(read_depth(write_exr(tmp_path / "d.exr", {"Y": z, "A": chroma + 1})), z)

    def test_multi_part_file(self, tmp_path):
        z = depth_with_holes(np.float32, seed=6)
        rgb = np.random.default_rng(7).random(z.shape).astype(np.float32)
        path = write_exr(
            tmp_path / "d.exr", None, parts={"beauty": {"R": rgb, "G": rgb * 2, "B": rgb * 3}, "depth": {"Z": z}}
        )
        np.testing.assert_array_equal(read_depth(path), z)

    def test_depth_scale_applies(self, tmp_path):
        z = np.full((4, 5), 1500.0, dtype=np.float32)  # millimetres
        np.testing.assert_allclose(read_depth(write_exr(tmp_path / "d.exr", {"Z": z}), depth_scale=1000), 1.5)

    def test_colour_image_is_not_depth(self, tmp_path):
        rgb = np.random.default_rng(8).random((6, 7, 3)).astype(np.float32)
        path = write_exr(tmp_path / "c.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
        with pytest.raises(
            DataFileError, match=r"c\.exr: expected one depth channel, got the colour channels .*differ"
        ):
            read_depth(path)

    def test_two_depth_channels(self, tmp_path):
        z = depth_with_holes()
        path = write_exr(tmp_path / "two.exr", {"Z": z, "depth": z * 2})
        with pytest.raises(
            DataFileError,
            match=r"two\.exr: expected one depth channel, got 2 \(Z, depth\)|"
            r"two\.exr: expected one depth channel, got 2 \(depth, Z\)",
        ):
            read_depth(path)

    def test_no_depth_channel(self, tmp_path):
        z = depth_with_holes()
        path = write_exr(tmp_path / "uv.exr", {"U": z, "V": z})
        with pytest.raises(
            DataFileError, match=r"uv\.exr: expected one depth channel \(named Z, depth.*got channels U, V"
        ):
            read_depth(path)

    def test_integer_channel_is_refused(self, tmp_path):
        path = write_exr(tmp_path / "u.exr", {"Z": np.arange(20, dtype=np.uint32).reshape(4, 5)})
        with pytest.raises(
            DataFileError,
            match=r"u\.exr: expected a float16 \(HALF\) or float32 \(FLOAT\) depth channel, "
            r"got channel 'Z' of dtype uint32",
        ):
            read_depth(path)

    @pytest.mark.parametrize("keep", [0.999, 0.9, 0.5, 0.2])
    def test_truncated_file_names_the_file_and_prints_nothing_else(self, tmp_path, capfd, keep):
        z = np.random.default_rng(9).uniform(0.5, 3.0, (240, 320)).astype(np.float32)  # several compressed chunks
        full = write_exr(tmp_path / "full.exr", {"Z": z}).read_bytes()
        cut = tmp_path / "cut.exr"
        cut.write_bytes(full[: int(len(full) * keep)])
        capfd.readouterr()
        with pytest.raises(DataFileError, match=r"cut\.exr: cannot read as OpenEXR depth \(truncated or corrupt: .+\)"):
            read_depth(cut)
        out, err = capfd.readouterr()
        assert out == "" and err == ""  # the library's own complaints are in the message, not on the terminal

    def test_not_an_exr_file(self, tmp_path):
        pytest.importorskip("OpenEXR")
        (tmp_path / "fake.exr").write_bytes(b"P5 2 2 65535\n" + bytes(8))
        (tmp_path / "empty.exr").write_bytes(b"")
        for name in ("fake.exr", "empty.exr"):
            with pytest.raises(
                DataFileError,
                match=rf"{name.replace('.', r'[.]')}: cannot read as OpenEXR depth "
                r"\(empty, or not an OpenEXR file\)",
            ):
                read_depth(tmp_path / name)

    def test_missing_file(self, tmp_path):
        pytest.importorskip("OpenEXR")
        with pytest.raises(DataFileError, match=r"nope\.exr: cannot read depth file \(No such file or directory\)"):
            read_depth(tmp_path / "nope.exr")

    def test_without_the_openexr_package_names_the_extra(self, tmp_path, monkeypatch):
        (tmp_path / "d.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(100))
        monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR now raises ImportError
        with pytest.raises(
            MissingDependencyError,
            match=r"d\.exr: reading OpenEXR depth needs the OpenEXR package: "
            r"pip install 'surfnorm\[exr\]'",
        ):
            read_depth(tmp_path / "d.exr")

    @pytest.mark.parametrize("name", ["d435_080", "d435_123", "cgsyn_002"])
    def test_real_frames_match_the_sample_depth(self, name):
        """RealSense D435 (NaN holes) and a Blender render (float16), as ClearGrasp published them."""
        pytest.importorskip("OpenEXR")
        folder = sensor_frame(name)
        out = read_depth(folder / "raw.exr")
        ref = np.load(folder / "depth.npy")
        assert out.shape == ref.shape
        np.testing.assert_array_equal(np.nan_to_num(out, nan=0.0), ref)  # depth.npy: NaN holes became 0


# ---------------------------------------------------------------------------- 16-bit PGM


def pgm_bytes(values: np.ndarray, maxval: int = 65535, *, little: bool = False, comment: bool = True) -> bytes:
    """A binary (P5) graymap as the netpbm specification defines it; ``little`` writes libfreenect's byte order."""
    h, w = values.shape
    header = b"P5\n" + (b"# written by hand\n" if comment else b"") + f"{w} {h}\n{maxval}\n".encode()
    return header + values.astype("<u2" if little else ">u2").tobytes()


class TestPgm:
    def test_big_endian_per_netpbm(self, tmp_path):
        v = np.array([[0, 1, 255], [256, 4660, 65535]], dtype=np.uint16)  # 4660 = 0x1234: the byte order shows
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(v))
        out = read_depth(tmp_path / "d.pgm")
        np.testing.assert_array_equal(out, v.astype(np.float32))

    def test_maxval_below_65535_keeps_raw_values(self, tmp_path):
        v = np.array([[0, 800], [1092, 2047]], dtype=np.uint16)  # 11-bit Kinect values, maxval 2047
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(v, 2047, comment=False))
        np.testing.assert_array_equal(read_depth(tmp_path / "d.pgm"), v)

    def test_depth_scale(self, tmp_path):
        v = np.full((3, 4), 1234, dtype=np.uint16)
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(v))
        np.testing.assert_allclose(read_depth(tmp_path / "d.pgm", depth_scale=1000), 1.234, rtol=1e-6)

    def test_little_endian_dump(self, tmp_path):
        v = np.array([[1, 4660], [800, 2047]], dtype=np.uint16)
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(v, little=True))
        np.testing.assert_array_equal(read_depth(tmp_path / "d.pgm", byte_order="little"), v)
        np.testing.assert_array_equal(read_depth(tmp_path / "d.pgm", byte_order="big"), v.byteswap())

    def test_truncated(self, tmp_path):
        raw = pgm_bytes(np.arange(64, dtype=np.uint16).reshape(8, 8))
        (tmp_path / "cut.pgm").write_bytes(raw[:-5])
        with pytest.raises(
            DataFileError, match=r"cut\.pgm: cannot decode as depth image|cut\.pgm: cannot decode as an image"
        ):
            read_depth(tmp_path / "cut.pgm")

    def test_eight_bit_graymap_is_a_picture(self, tmp_path):
        (tmp_path / "g.pgm").write_bytes(b"P5\n3 2\n255\n" + bytes(range(6)))
        with pytest.raises(
            DataFileError, match=r"g\.pgm: expected 16-bit integer or 32-bit float depth, got an 8-bit image"
        ):
            read_depth(tmp_path / "g.pgm")

    def test_colour_pixmap_is_refused(self, tmp_path):
        (tmp_path / "c.pgm").write_bytes(b"P6\n2 1\n65535\n" + bytes(12))
        with pytest.raises(DataFileError, match=r"c\.pgm: expected a single-channel depth image, got 3 channels"):
            read_depth(tmp_path / "c.pgm")

    def test_byte_order_only_for_pgm(self, tmp_path):
        np.save(tmp_path / "d.npy", np.ones((2, 2), np.float32))
        with pytest.raises(
            InputError, match=r"byte_order: applies to 16-bit \.pgm files, got byte_order='little' for a \.npy file"
        ):
            read_depth(tmp_path / "d.npy", byte_order="little")

    def test_bad_byte_order(self, tmp_path):
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(np.ones((2, 2), np.uint16)))
        with pytest.raises(InputError, match=r"byte_order: expected one of 'big', 'little', got 'native'"):
            read_depth(tmp_path / "d.pgm", byte_order="native")


# ---------------------------------------------------------------------------- PFM


def pfm_bytes(values: np.ndarray, *, little: bool = True, header: bytes | None = None, colour: bool = False) -> bytes:
    """A Portable Float Map written from its description: a header ("Pf", or "PF" for colour; width, height; the
    scale, negative for little-endian samples), then float32 rows from the bottom row up."""
    h, w = values.shape[:2]
    scale = -1.0 / 255 if little else 1.0 / 255  # Middlebury's magnitude, which readers ignore
    head = header if header is not None else (b"PF" if colour else b"Pf") + f"\n{w} {h}\n{scale}\n".encode()
    return head + np.ascontiguousarray(values[::-1]).astype("<f4" if little else ">f4").tobytes()


class TestPfm:
    VALUES = np.array([[1.5, 2.25, np.inf], [-3.0, 0.0, 1e-3]], dtype=np.float32)  # inf: Middlebury's unknown

    @pytest.mark.parametrize("little", [True, False])
    def test_rows_come_back_top_to_bottom_in_either_byte_order(self, tmp_path, little):
        (tmp_path / "d.pfm").write_bytes(pfm_bytes(self.VALUES, little=little))
        out = read_depth(tmp_path / "d.pfm")
        assert out.dtype == np.float32 and out.shape == (2, 3)
        np.testing.assert_array_equal(out, self.VALUES)  # the scale's magnitude (1/255) not applied

    def test_header_fields_separated_by_any_whitespace(self, tmp_path):
        # SceneFlow writes a space before each line break ("Pf \n960 540 \n-1.0\n"), which OpenCV's decoder refuses
        for header in (b"Pf \n3 2 \n-1.0\n", b"Pf\r\n3 2\r\n-1.0\r\n", b"Pf 3\t2 -1.0 "):  # and Windows line breaks
            (tmp_path / "d.pfm").write_bytes(pfm_bytes(self.VALUES, header=header))
            np.testing.assert_array_equal(read_depth(tmp_path / "d.pfm"), self.VALUES)

    def test_depth_scale_and_estimate(self, tmp_path):
        v = np.full((3, 4), 1500.0, np.float32)
        (tmp_path / "d.pfm").write_bytes(pfm_bytes(v))
        np.testing.assert_array_equal(read_depth(tmp_path / "d.pfm", depth_scale=1000), np.float32(1.5))

    def test_truncated_or_longer(self, tmp_path):
        raw = pfm_bytes(self.VALUES)
        (tmp_path / "cut.pfm").write_bytes(raw[:-5])
        with pytest.raises(
            DataFileError, match=r"cut\.pfm: expected 24 bytes of pixels for 3 x 2, got 19 \(truncated\)"
        ):
            read_depth(tmp_path / "cut.pfm")
        (tmp_path / "long.pfm").write_bytes(raw + b"\0")
        with pytest.raises(DataFileError, match=r"long\.pfm: expected 24 bytes of pixels .* got 25 \(longer than"):
            read_depth(tmp_path / "long.pfm")

    def test_colour_map_is_not_depth(self, tmp_path):
        (tmp_path / "c.pfm").write_bytes(pfm_bytes(np.zeros((2, 3, 3), np.float32), colour=True))
        with pytest.raises(DataFileError, match=r"c\.pfm: expected a single-channel depth map \('Pf'\), got a 3-chan"):
            read_depth(tmp_path / "c.pfm")

    @pytest.mark.parametrize(
        "raw, what",
        [
            (b"P5\n3 2\n65535\n" + bytes(12), "expected a PFM file"),
            (b"Pf\n3 two\n-1.0\n" + bytes(24), "expected a PFM header of width, height and scale, got '3 two -1.0'"),
            (
                b"Pf\n0 2\n-1.0\n",
                "expected a PFM header of a positive width and height and a non-zero scale, got 0 x 2",
            ),
            (b"Pf\n3 2\n0\n" + bytes(24), "a positive width and height and a non-zero scale, got 3 x 2, scale 0.0"),
            (b"Pf\n3 2\n-1.0", "expected a PFM file"),
            (b"", "expected a PFM file"),
        ],
    )
    def test_not_a_pfm_file(self, tmp_path, raw, what):
        (tmp_path / "x.pfm").write_bytes(raw)
        with pytest.raises(DataFileError, match=r"x\.pfm: (expected a PFM header of )?" + re.escape(what)):
            read_depth(tmp_path / "x.pfm")

    def test_cli_estimate_reads_pfm_disparity(self, tmp_path):
        """A learned stereo matcher's PFM disparity through the CLI with --disparity: the normals of the depth."""
        from typer.testing import CliRunner

        from surfnorm.cli import app
        from surfnorm.io import disparity_to_depth

        v, u = np.mgrid[0:48, 0:64]
        depth = (1.5 + 0.004 * u + 0.002 * v).astype(np.float32)
        disparity = (580.0 * 0.1 / depth).astype(np.float32)
        (tmp_path / "disp.pfm").write_bytes(pfm_bytes(disparity))
        result = CliRunner().invoke(
            app, ["estimate", str(tmp_path / "disp.pfm"), str(tmp_path / "n"), "--disparity", *CAMERA]
        )
        assert result.exit_code == 0, result.output
        n = np.load(tmp_path / "n.npy")
        K = np.array([[580.0, 0, 31.5], [0, 580.0, 23.5], [0, 0, 1]])
        expected = surfnorm.estimate(disparity_to_depth(disparity, 0.1, 580.0), K, scale_invariant=True)
        np.testing.assert_allclose(n, expected, atol=1e-4)


# ---------------------------------------------------------------------------- Kinect v1 disparity


class TestKinectDisparity:
    def test_nyu_toolbox_formula(self):
        d = np.array([[0.0, 500.0, 800.0, 1000.0]])
        expected = 351.3 / (1092.5 - d)
        np.testing.assert_allclose(kinect_disparity_to_depth(d), expected.astype(np.float32), rtol=1e-6)
        assert KINECT_V1_NYU == {"a": 351.3, "b": 1092.5, "max_depth": 10.0}

    def test_no_reading_and_out_of_range_are_invalid(self):
        # 2047: the sensor's "no reading"; 1092.5 - d <= 0: no positive depth; 1060: 10.8 m, beyond NYU's 10 m;
        # negative and NaN: not disparity
        d = np.array([[2047.0, 1092.5, 1100.0, 1060.0, -1.0, np.nan, 1050.0]])
        z = kinect_disparity_to_depth(d)
        np.testing.assert_array_equal(z[0, :6], 0.0)
        assert z[0, 6] == pytest.approx(351.3 / 42.5, rel=1e-6)  # 8.27 m stays
        assert kinect_disparity_to_depth(np.array([[1060.0]]), max_depth=None)[0, 0] == pytest.approx(
            351.3 / 32.5, rel=1e-6
        )

    def test_other_constants(self):
        z = kinect_disparity_to_depth(np.array([[100.0]]), a=300.0, b=1000.0)
        assert z[0, 0] == pytest.approx(300.0 / 900.0, rel=1e-6)
        with pytest.raises(InputError, match=r"^a: expected a positive finite number, got -1"):
            kinect_disparity_to_depth(np.zeros((1, 1)), a=-1)

    def test_nyu_raw_frame(self, tmp_path):
        """An NYU Depth v2 raw frame: libfreenect dump (little-endian P5) of 11-bit disparity."""
        rng = np.random.default_rng(10)
        d = rng.integers(400, 1040, (48, 64)).astype(np.uint16)
        d[rng.random(d.shape) < 0.05] = 2047
        (tmp_path / "d-1316558342.8-2944600483.pgm").write_bytes(pgm_bytes(d, little=True))
        z = read_depth(tmp_path / "d-1316558342.8-2944600483.pgm", kinect_disparity=True, byte_order="little")
        expected = np.where(d == 2047, 0.0, 351.3 / (1092.5 - d.astype(np.float64)))
        np.testing.assert_allclose(z, expected.astype(np.float32), rtol=1e-6)
        assert z.dtype == np.float32

    def test_swapped_bytes_are_detected(self, tmp_path):
        d = np.full((4, 4), 800, dtype=np.uint16)
        (tmp_path / "d.pgm").write_bytes(pgm_bytes(d, little=True))
        with pytest.raises(
            DataFileError,
            match=r"d\.pgm: expected Kinect v1 raw disparity \(11 bits, 0 to 2047\), "
            r"got values up to 8195; with the bytes swapped they are: "
            r"pass byte_order='little'",
        ):
            read_depth(tmp_path / "d.pgm", kinect_disparity=True)

    def test_from_other_containers(self, tmp_path):
        d = np.array([[600, 700], [2047, 900]], dtype=np.uint16)
        np.save(tmp_path / "d.npy", d)
        z = read_depth(tmp_path / "d.npy", kinect_disparity=True)
        np.testing.assert_allclose(z, kinect_disparity_to_depth(d))
        assert z[1, 0] == 0

    def test_not_with_depth_scale(self, tmp_path):
        np.save(tmp_path / "d.npy", np.zeros((2, 2), np.uint16))
        with pytest.raises(InputError, match=r"depth_scale: expected None with kinect_disparity=True"):
            read_depth(tmp_path / "d.npy", kinect_disparity=True, depth_scale=1000)
        with pytest.raises(InputError, match=r"kinect_disparity: expected True or False, got 'yes'"):
            read_depth(tmp_path / "d.npy", kinect_disparity="yes")

    def test_plane_comes_back_flat(self, tmp_path):
        """A tilted plane coded as integer disparity gives depth on that plane up to the disparity step."""
        H, W, f = 60, 80, 580.0
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        # plane n . X = c with X = z ((u - cx) / f, (v - cy) / f, 1): z = c / (n . ray)
        n, c = np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0]), -2.0
        ray = np.stack([(u - W / 2) / f, (v - H / 2) / f, np.ones_like(u)], axis=-1)
        z_true = c / (ray @ n)
        d = np.rint(1092.5 - 351.3 / z_true).astype(np.uint16)
        (tmp_path / "plane.pgm").write_bytes(pgm_bytes(d, little=True))
        z = read_depth(tmp_path / "plane.pgm", kinect_disparity=True, byte_order="little").astype(np.float64)
        step = 351.3 / (1092.5 - d - 1) - 351.3 / (1092.5 - d)  # one disparity step in metres
        assert np.all(np.abs(z - z_true) <= step / 2 + 1e-6)


# ---------------------------------------------------------------------------- SUN RGB-D


def sun_rgbd_stored(mm: np.ndarray) -> np.ndarray:
    """Millimetres as SUN RGB-D stores them: 16 bits rotated left by 3 (written here from its description)."""
    mm = mm.astype(np.uint32)
    return (((mm << 3) & 0xFFFF) | (mm >> 13)).astype(np.uint16)


class TestSunRgbd:
    def test_rotated_millimetres_come_back_as_metres(self, tmp_path):
        import cv2

        mm = np.array([[0, 1, 1500, 8191], [8192, 9870, 12000, 65535]], dtype=np.uint16)  # 8.192 m and more wrap
        cv2.imwrite(str(tmp_path / "0001.png"), sun_rgbd_stored(mm))
        z = read_depth(tmp_path / "0001.png", sun_rgbd=True)
        np.testing.assert_array_equal(z, (mm / 1000.0).astype(np.float32))
        assert z.dtype == np.float32 and z[0, 0] == 0  # no depth stays no depth
        # read as plain millimetres, the near depth is 8 times too large and the far depth wraps
        plain = read_depth(tmp_path / "0001.png", depth_scale=1000)
        assert plain[0, 2] == pytest.approx(12.0) and plain[1, 1] == pytest.approx(13.425)
        np.testing.assert_array_equal(sun_rgbd_to_depth(sun_rgbd_stored(mm)), z)

    def test_from_other_containers(self, tmp_path):
        mm = np.array([[700, 2500]], dtype=np.uint16)
        np.save(tmp_path / "d.npy", sun_rgbd_stored(mm))
        np.testing.assert_allclose(read_depth(tmp_path / "d.npy", sun_rgbd=True), [[0.7, 2.5]], rtol=1e-6)

    def test_refusals(self, tmp_path):
        import cv2

        cv2.imwrite(str(tmp_path / "d.png"), np.ones((2, 2), np.uint16))
        with pytest.raises(InputError, match=r"^depth_scale: expected None with sun_rgbd=True"):
            read_depth(tmp_path / "d.png", sun_rgbd=True, depth_scale=1000)
        with pytest.raises(InputError, match=r"^sun_rgbd: expected False with kinect_disparity=True"):
            read_depth(tmp_path / "d.png", sun_rgbd=True, kinect_disparity=True)
        with pytest.raises(InputError, match=r"^sun_rgbd: expected True or False, got 'yes'"):
            read_depth(tmp_path / "d.png", sun_rgbd="yes")
        np.save(tmp_path / "f.npy", np.ones((2, 2), np.float32))
        with pytest.raises(
            DataFileError, match=r"f\.npy: expected SUN RGB-D's 16-bit integer depth, got dtype float32"
        ):
            read_depth(tmp_path / "f.npy", sun_rgbd=True)
        np.save(tmp_path / "b.npy", np.full((2, 2), 80, np.uint8))
        with pytest.raises(DataFileError, match=r"b\.npy: expected SUN RGB-D's 16-bit integer depth, got dtype uint8"):
            read_depth(tmp_path / "b.npy", sun_rgbd=True)
        np.save(tmp_path / "w.npy", np.full((2, 2), 70000, np.int32))
        with pytest.raises(
            DataFileError, match=r"w\.npy: expected SUN RGB-D's 16-bit depth \(0 to 65535\), got values"
        ):
            read_depth(tmp_path / "w.npy", sun_rgbd=True)
        with pytest.raises(InputError, match=r"^raw: expected 16-bit integers .*, got dtype float64"):
            sun_rgbd_to_depth(np.ones((2, 2)))
        with pytest.raises(InputError, match=r"^raw: expected 16-bit integers .*, got values from -1 to 70000"):
            sun_rgbd_to_depth(np.array([[-1, 70000]]))


def test_cli_and_convert_read_sun_rgbd(tmp_path):
    import cv2
    from typer.testing import CliRunner

    from surfnorm.batch import convert
    from surfnorm.cli import app

    v, u = np.mgrid[0:48, 0:64]
    mm = np.rint(1000 * (2.0 + 0.01 * u + 0.005 * v)).astype(np.uint16)  # a tilted plane, 2-2.9 m
    src = tmp_path / "sun"
    src.mkdir()
    cv2.imwrite(str(src / "0001.png"), sun_rgbd_stored(mm))
    result = CliRunner().invoke(app, ["estimate", str(src / "0001.png"), str(tmp_path / "n"), "--sun-rgbd", *CAMERA])
    assert result.exit_code == 0, result.output
    import surfnorm

    K = np.array([[580.0, 0, 31.5], [0, 580.0, 23.5], [0, 0, 1]])
    want = surfnorm.estimate((mm / 1000.0).astype(np.float32), K)
    np.testing.assert_array_equal(np.load(tmp_path / "n.npy"), want)
    summary = convert(src, tmp_path / "out", intrinsics=K, sun_rgbd=True)
    assert summary.ok and summary.written == 1, summary.errors
    np.testing.assert_array_equal(np.load(tmp_path / "out" / "0001.npy"), want)
    result = CliRunner().invoke(
        app, ["convert", str(src), str(tmp_path / "o2"), "--sun-rgbd", "--depth-scale", "1000", *CAMERA]
    )
    assert result.exit_code == 2 and "depth_scale: expected None with sun_rgbd=True" in result.output, result.output


# ---------------------------------------------------------------------------- the sample's PNG frames


@pytest.mark.parametrize(
    "name, scale", [("nyu_sync_00100", 1000.0), ("redwood_00000", 1000.0), ("kitti_0000000005", 256.0)]
)
def test_real_png_frames_match_the_sample_depth(name, scale):
    folder = sensor_frame(name)
    out = read_depth(folder / "raw.png", depth_scale=scale)
    np.testing.assert_allclose(out, np.load(folder / "depth.npy"), rtol=1e-6, atol=0)
    assert json.loads((folder / "K.json").read_text())["fx"] > 0


# ---------------------------------------------------------------------------- the command line


def _plane_disparity(H=48, W=64) -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W]
    z = 1.5 + 0.004 * u + 0.002 * v  # metres, a tilted plane
    return np.rint(1092.5 - 351.3 / z).astype(np.uint16)


CAMERA = ["--fx", "580", "--fy", "580", "--cx", "31.5", "--cy", "23.5"]


def test_cli_estimate_reads_exr_and_nyu_pgm(tmp_path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    runner = CliRunner()
    pgm = tmp_path / "d-1.pgm"
    pgm.write_bytes(pgm_bytes(_plane_disparity(), little=True))
    result = runner.invoke(
        app, ["estimate", str(pgm), str(tmp_path / "nyu"), "--kinect-disparity", "--byte-order", "little", *CAMERA]
    )
    assert result.exit_code == 0, result.output
    n = np.load(tmp_path / "nyu.npy")
    assert n.shape == (48, 64, 3) and np.isfinite(n).all() and (n[..., 2] < 0).mean() > 0.9

    pytest.importorskip("OpenEXR")
    depth = read_depth(pgm, kinect_disparity=True, byte_order="little")
    exr = write_exr(tmp_path / "d.exr", {"Z": depth})
    result = runner.invoke(app, ["estimate", str(exr), str(tmp_path / "exr"), *CAMERA])
    assert result.exit_code == 0, result.output
    np.testing.assert_array_equal(np.load(tmp_path / "exr.npy"), n)  # the same depth gives the same normals


def test_cli_raw_options_misused_exit_2(tmp_path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    runner = CliRunner()
    np.save(tmp_path / "d.npy", np.ones((8, 8), np.float32))
    (tmp_path / "big.pgm").write_bytes(pgm_bytes(_plane_disparity(), little=True))
    cases = [
        (
            ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "x"), "--byte-order", "little", *CAMERA],
            "byte_order: applies to 16-bit .pgm files",
        ),
        (
            ["estimate", str(tmp_path / "big.pgm"), str(tmp_path / "x"), "--kinect-disparity", *CAMERA],
            "pass byte_order='little'",
        ),
    ]
    for args, text in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert text in result.output and "Traceback" not in result.output


def test_convert_folder_of_nyu_pgm_and_exr(tmp_path):
    from surfnorm.batch import convert

    src = tmp_path / "raw"
    src.mkdir()
    d = _plane_disparity()
    for i in range(2):
        (src / f"d-{i}.pgm").write_bytes(pgm_bytes(d, little=True))
    np.save(src / "ok.npy", kinect_disparity_to_depth(d).astype(np.uint16))  # another file type in the folder
    K = np.array([[580.0, 0, 31.5], [0, 580.0, 23.5], [0, 0, 1]])
    summary = convert(src, tmp_path / "out", intrinsics=K, byte_order="little")  # byte_order: for the .pgm files only
    assert summary.ok and summary.written == 3, summary.errors
    summary = convert(src / "d-*.pgm", tmp_path / "out2", intrinsics=K, kinect_disparity=True, byte_order="little")
    assert summary.ok and summary.written == 2
    expected = np.load(tmp_path / "out2" / "d-0.npy")
    assert expected.shape == (48, 64, 3) and (expected[..., 2] < 0).mean() > 0.9
    write_exr(src / "e.exr", {"Z": kinect_disparity_to_depth(d)})
    summary = convert(src / "e.exr", tmp_path / "out3", intrinsics=K)
    assert summary.ok, summary.errors
    np.testing.assert_array_equal(np.load(tmp_path / "out3" / "e.npy"), expected)
