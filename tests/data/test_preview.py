"""Preview PNG: the figure with synthetic tactile images, and the CLI end to end with a tiny simulation."""

import os

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from tvrecon.data.preview import draw_preview, main, save_figure_atomic
from tvrecon.data.touches.policies import ConeTouchPolicy, sample_touches
from tvrecon.data.views import render_view, sample_camera

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_draw_and_atomic_save(tmp_path) -> None:
    mesh = trimesh.creation.torus(0.3, 0.12)
    cam = sample_camera(0, image_size=64)
    view = render_view(mesh, cam, seed=0)
    tt = sample_touches(mesh, 5, 0, ConeTouchPolicy(visible_only=True), camera=cam)
    yy, xx = torch.meshgrid(torch.arange(16.0), torch.arange(16.0), indexing="ij")
    blob = torch.exp(-((yy - 8) ** 2 + (xx - 7) ** 2) / 10)
    tactile = torch.stack([torch.stack([0.1 * blob, -0.1 * blob, blob * (t + 1)]) for t in range(5)])
    fig = draw_preview(view["image"], cam, tt.positions, tt.directions, tactile, labels=list("abcde"), title="x")
    out = save_figure_atomic(fig, tmp_path / "sub" / "p.png")
    assert out.read_bytes()[:8] == PNG_MAGIC
    with Image.open(out) as im:
        w, h = im.size
        arr = np.asarray(im.convert("RGB"))
    assert w > 400 and h > 200
    assert arr.std() > 10  # not a blank canvas
    assert os.listdir(tmp_path / "sub") == ["p.png"]  # no temp file left behind
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(ValueError, match=r"tactile must have shape \(T, 3, h, w\)"):
        draw_preview(view["image"], cam, tt.positions, tt.directions, tactile[:2])


@pytest.mark.slow
def test_cli_writes_png(tmp_path, capsys) -> None:
    out = tmp_path / "preview.png"
    argv = ["--out", str(out), "--shape", "torus", "--touches", "2", "--seed", "1", "--image-size", "64"]
    argv += ["--pad", "8", "--n-grid", "64"]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny simulations: single-threaded is much faster on a busy machine
    try:
        assert main(argv) == 0
    finally:
        torch.set_num_threads(threads)
    assert out.read_bytes()[:8] == PNG_MAGIC
    with Image.open(out) as im:
        assert im.size[0] > 300
    assert "wrote" in capsys.readouterr().out
    assert sorted(os.listdir(tmp_path)) == ["preview.png"]


def test_cli_rejects_unknown_shape(tmp_path) -> None:
    with pytest.raises(ValueError, match="is neither an object class nor an existing mesh file"):
        main(["--out", str(tmp_path / "x.png"), "--shape", "no-such-shape"])
