"""``data.device_tactile_size``: the tactile resize after the batch reaches the device equals the load-time resize."""

from pathlib import Path

import lightning as L
import pytest
import torch
from torch import nn

from tvrecon.data.datamodule import ClassificationDataModule, device_resize
from tvrecon.data.touches.policies import resize_tactile

# tiny simulation (about 1 s for the 2 objects x 3 touches): 8x8 pad, 3 layers, 32^3 grid
SIM = {
    "sensor": {"resolution": (8, 8), "layers": 3},
    "press": {"n_grid": 32, "max_depth": 1.5, "gap": 0.5, "speed_fraction": 0.2},
    "touch": {"strengths": [{"threshold": 0.05}], "cone_deg": 10.0},
}
SIZE = 20


def datamodule(cache: Path, **over) -> ClassificationDataModule:
    args = dict(
        train={"num_objects": 2, "classes": ["cube", "torus"]},
        test={"num_objects": 2, "classes": ["cube", "torus"]},
        batch_size=2,
        cache_dir=cache,
        touches_per_object=3,
        num_touches=2,
        tactile_scale=0.5,
        **SIM,
    )
    args.update(over)
    return ClassificationDataModule(**args)


def test_resize_after_transfer_equals_resize_on_load(tmp_path: Path) -> None:
    on_load = datamodule(tmp_path, tactile_size=SIZE)
    on_device = datamodule(tmp_path, tactile_size=8, device_tactile_size=SIZE)  # 8: the pad's own resolution
    expected = next(iter(on_load.test_dataloader()))
    small = next(iter(on_device.test_dataloader()))
    assert small["tactile"].shape == (2, 2, 3, 8, 8) and expected["tactile"].shape == (2, 2, 3, SIZE, SIZE)
    got = on_device.on_after_batch_transfer(small, 0)
    assert got["tactile"].shape == expected["tactile"].shape
    torch.testing.assert_close(got["tactile"], expected["tactile"], rtol=1e-6, atol=1e-6)
    assert expected["tactile"].abs().amax() > 0  # the touches felt something: the comparison is not of zeros
    for key in ("label", "touch_mask", "positions", "directions"):
        assert torch.equal(got[key], expected[key])


class _ShapeProbe(L.LightningModule):
    """Records the tactile shape each training step sees."""

    def __init__(self) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(()))
        self.shapes: list[tuple[int, ...]] = []

    def training_step(self, batch, batch_idx):
        self.shapes.append(tuple(batch["tactile"].shape))
        return (self.weight - batch["tactile"].mean()) ** 2

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_the_trainer_runs_the_hook(tmp_path: Path) -> None:
    dm = datamodule(tmp_path, tactile_size=8, device_tactile_size=SIZE, val=None)
    probe = _ShapeProbe()
    trainer = L.Trainer(
        max_steps=1,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    trainer.fit(probe, datamodule=dm)
    assert probe.shapes == [(2, 2, 3, SIZE, SIZE)]


def test_bad_sizes_and_batches_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="device_tactile_size"):
        datamodule(tmp_path, device_tactile_size=0)
    with pytest.raises(ValueError, match=r"\(B,T,3,h,w\)"):
        device_resize({"tactile": torch.zeros(2, 3, 8, 8)}, SIZE)


def test_no_size_or_no_tactile_leaves_the_batch_as_it_is() -> None:
    batch = {"tactile": torch.rand(2, 3, 3, 8, 8)}
    assert device_resize(batch, None) is batch
    assert device_resize({"image": torch.zeros(1)}, SIZE).keys() == {"image"}
    empty = device_resize({"tactile": torch.zeros(2, 0, 3, 8, 8)}, SIZE)["tactile"]
    assert empty.shape == (2, 0, 3, SIZE, SIZE)
    one = torch.rand(1, 1, 3, 8, 8)
    assert torch.equal(device_resize({"tactile": one}, SIZE)["tactile"][0], resize_tactile(one[0], SIZE))
