"""Frame sources (rdnet.sim.sources): video, image folders, HDF5 recordings."""
import cv2
import numpy as np
import pytest

from rdnet.errors import ConfigError, FormatError
from rdnet.events import Frames, Recording
from rdnet.sim.scenes import srgb_to_linear
from rdnet.sim.sources import iter_frames, open_frames


def _frames_u8(n=6, h=24, w=32, color=True):
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.random((h, w + 3 * n)).astype(np.float32), (0, 0), 2)
    base = (base - base.min()) / (base.max() - base.min())
    ims = [np.uint8(np.clip(base[:, 3 * i:3 * i + w] * 255, 0, 255)) for i in range(n)]
    if color:
        ims = [np.stack([im, im // 2, 255 - im], -1) for im in ims]        # BGR
    return ims


def test_png_folder_gopro_layout(tmp_path):
    ims = _frames_u8(color=True)
    d = tmp_path / "GOPR0001" / "sharp"
    d.mkdir(parents=True)
    for i, im in enumerate(ims):           # natural order: 2 < 10
        cv2.imwrite(str(d / f"{i * 8:d}.png"), im)
    fr = open_frames(tmp_path / "GOPR0001")
    assert len(fr) == 6 and fr.images.shape == (6, 24, 32, 3) and fr.images.dtype == np.float32
    np.testing.assert_array_equal(fr.t_us, np.rint(np.arange(6) * 1e6 / 240).astype(np.int64))
    # BGR -> RGB and sRGB decoding
    np.testing.assert_allclose(fr.images[3], srgb_to_linear(ims[3][..., ::-1] / 255.0), atol=1e-6)
    raw = open_frames(d, max_frames=4, fps_hz=1000, linearize=False)
    assert len(raw) == 4
    np.testing.assert_array_equal(raw.t_us, [0, 1000, 2000, 3000])
    np.testing.assert_allclose(raw.images[1], ims[1][..., ::-1] / 255.0, atol=1e-6)
    chunks = list(iter_frames(d, chunk_frames=4))
    assert [len(c) for c in chunks] == [4, 2]
    np.testing.assert_array_equal(np.concatenate([c.t_us for c in chunks]), fr.t_us)


def test_mjpg_video(tmp_path):
    ims = _frames_u8(n=8, color=True)
    path = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (32, 24))
    assert vw.isOpened()
    for im in ims:
        vw.write(im)
    vw.release()
    fr = open_frames(path)
    assert len(fr) == 8 and fr.images.shape == (8, 24, 32, 3)
    np.testing.assert_array_equal(fr.t_us, np.arange(8) * 20_000)        # 50 fps
    ref = srgb_to_linear(ims[5][..., ::-1] / 255.0)
    assert np.abs(fr.images[5] - ref).mean() < 0.03                       # JPEG loss only
    fr2 = open_frames(path, max_frames=3, fps_hz=100)
    np.testing.assert_array_equal(fr2.t_us, [0, 10_000, 20_000])
    assert [len(c) for c in iter_frames(path, chunk_frames=3)] == [3, 3, 2]


def test_hdf5_recording(tmp_path):
    from rdnet.events.io import write_recording
    rng = np.random.default_rng(0)
    fr = Frames(rng.random((5, 6, 7), dtype=np.float32), np.array([3, 10, 20, 33, 50]), np.full(5, 2))
    path = tmp_path / "rec.h5"
    write_recording(path, Recording(7, 6, frames=fr))
    got = open_frames(path)                                               # stored as is
    np.testing.assert_array_equal(got.images, fr.images)
    np.testing.assert_array_equal(got.t_us, fr.t_us)
    np.testing.assert_array_equal(got.exposure_us, fr.exposure_us)
    got = open_frames(path, max_frames=2, linearize=True)
    np.testing.assert_allclose(got.images, srgb_to_linear(fr.images[:2]), atol=1e-7)


def test_bad_inputs(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        open_frames(tmp_path / "nope.avi")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FormatError, match="no image files"):
        open_frames(empty)
    (empty / "a.png").write_bytes(b"not a png")
    with pytest.raises(FormatError, match="cannot decode"):
        open_frames(empty)
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"\x00" * 100)
    with pytest.raises(FormatError):
        open_frames(bad)
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(FormatError, match="unsupported"):
        open_frames(tmp_path / "x.txt")
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    cv2.imwrite(str(mixed / "0.png"), np.zeros((4, 4), np.uint8))
    cv2.imwrite(str(mixed / "1.png"), np.zeros((5, 4), np.uint8))
    with pytest.raises(FormatError, match="shape"):
        open_frames(mixed)
    with pytest.raises(ConfigError, match="fps_hz"):
        open_frames(mixed, fps_hz=0)
    with pytest.raises(ConfigError, match="max_frames"):
        open_frames(mixed, max_frames=0)
    from rdnet.events import Events
    from rdnet.events.io import write_recording
    ev = Events.from_columns([1, 2], [0, 1], [0, 0], [1, 0], 4, 4)
    write_recording(tmp_path / "ev.h5", Recording(4, 4, events=ev))
    with pytest.raises(FormatError, match="frames"):
        open_frames(tmp_path / "ev.h5")


def test_a_truncated_video_is_refused(tmp_path):
    """An AVI cut at 60 % still opens and decodes its first frames; its header declares all
    of them, so the missing rest is an error, not a shorter clip."""
    ims = _frames_u8(n=20, color=True)
    path = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (32, 24))
    for im in ims:
        vw.write(im)
    vw.release()
    assert len(open_frames(path)) == 20
    data = path.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(FormatError, match="of the 20 frames its header declares"):
        open_frames(cut)
    assert len(open_frames(cut, max_frames=5)) == 5      # the frames asked for are all there


def test_frame_folder_refuses_broken_links_and_mixed_bit_depths(tmp_path):
    d = tmp_path / "frames"
    d.mkdir()
    for i in range(3):
        cv2.imwrite(str(d / f"{i}.png"), np.full((4, 4), 40 * i, np.uint8))
    assert len(open_frames(d)) == 3
    (d / "3.png").symlink_to(tmp_path / "gone.png")
    with pytest.raises(FormatError, match="broken symbolic link") as e:
        open_frames(d)
    assert "3.png" in str(e.value)
    (d / "3.png").unlink()
    cv2.imwrite(str(d / "3.png"), np.full((4, 4), 40 * 256, np.uint16))
    with pytest.raises(FormatError, match="uint16 .16-bit.*uint8 .8-bit") as e:
        open_frames(d)
    assert "3.png" in str(e.value)
