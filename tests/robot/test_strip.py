"""Run figures (GIF, MP4, strip) from a synthetic pick-and-place log."""

from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from tvrecon.robot.strip import write_gif, write_mp4, write_strip


def _log(k: int = 6, hw: tuple[int, int] = (48, 64)) -> dict:
    rng = np.random.default_rng(0)
    tactile = np.zeros((k, 2, 3, 8, 8), np.float32)
    tactile[k // 2 :, :, 2] = rng.random((k - k // 2, 2, 8, 8))  # contact in the second half
    return {
        "frames": rng.integers(0, 255, (k, *hw, 3), dtype=np.uint8),
        "tactile": tactile,
        "contact": np.repeat((np.arange(k) >= k // 2)[:, None], 2, axis=1),
        "phase": np.repeat(np.arange(2), k // 2),
        "phase_names": np.array(["approach", "squeeze"]),
        "time": np.arange(k, dtype=np.float32) / 30,
        "force": np.zeros((k, 2), np.float32),
    }


def test_gif_and_strip_are_written_atomically(tmp_path: Path) -> None:
    log = _log()
    gif = write_gif(log, tmp_path / "run.gif")
    assert len(imageio.mimread(gif)) == 6
    assert write_strip(log, tmp_path / "strip.png").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.gif", "strip.png"]


def test_mp4_has_every_frame_and_even_size(tmp_path: Path) -> None:
    pytest.importorskip("imageio_ffmpeg")
    log = _log(k=8, hw=(47, 63))  # odd sizes: padded to even for yuv420p
    mp4 = write_mp4(log, tmp_path / "run.mp4", fps=10)
    frames = imageio.mimread(mp4, format="FFMPEG")
    assert len(frames) == 8
    h, w = frames[0].shape[:2]
    assert h % 2 == 0 and w % 2 == 0 and h == 48
    assert [p.name for p in tmp_path.iterdir()] == ["run.mp4"]  # no temporary file left


def test_empty_log_is_refused_and_leaves_nothing(tmp_path: Path) -> None:
    log = _log()
    log["frames"] = log["frames"][:0]
    with pytest.raises(ValueError, match="no frames"):
        write_gif(log, tmp_path / "run.gif")
    with pytest.raises((ValueError, ImportError)):
        write_mp4(log, tmp_path / "run.mp4")
    assert not list(tmp_path.iterdir())
