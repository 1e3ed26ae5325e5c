"""Classify objects from their touches with a trained tactile classifier (the paper's Table 2 model).

    python train.py experiment=classify_paper_cpu model.num_touches=10              # a run folder to classify with
    python examples/classify_touches.py --run logs/train/runs/<time>
    python examples/classify_touches.py --run logs/train/runs/<time> --split val --objects 5

The run folder's ``.hydra/config.yaml`` rebuilds the classifier and its data; its checkpoint (``last.ckpt``, else
the newest) gives the weights. Each object of the split is touched N times (the model's ``num_touches``), the same
touches the simulator made for the dataset, and the script prints the object's class, the three most likely classes
with their probabilities, and the accuracy over the objects shown.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import hydra
import torch
from omegaconf import OmegaConf

from tvrecon.utils.cli_errors import run_cli


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="classify_touches.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="a train.py run folder of a classifier")
    p.add_argument("--split", choices=("train", "val", "test"), default="test", help="objects to classify")
    p.add_argument("--objects", type=int, default=10, help="how many objects of the split (default 10)")
    return p


def load_classifier(run: Path) -> tuple[torch.nn.Module, object]:
    """The run's LightningModule (weights loaded, eval mode) and its datamodule, rebuilt from its config."""
    config = run / ".hydra" / "config.yaml"
    if not config.is_file():
        raise ValueError(f"--run {run}: no .hydra/config.yaml; give the folder train.py wrote (logs/train/runs/<time>)")
    ckpts = sorted((run / "checkpoints").glob("*.ckpt"), key=lambda p: (p.name != "last.ckpt", -p.stat().st_mtime))
    if not ckpts:
        raise ValueError(f"--run {run}: no checkpoints/*.ckpt; the run has not finished an epoch")
    cfg = OmegaConf.load(config)
    if not str(cfg.model._target_).endswith("ClassificationModule"):
        raise ValueError(f"--run {run} holds a {cfg.model._target_}, not a classifier (train.py experiment=classify)")
    model = hydra.utils.instantiate(cfg.model)
    state = torch.load(ckpts[0], map_location="cpu", weights_only=True)
    model.load_state_dict(state["state_dict"])
    return model.eval(), hydra.utils.instantiate(cfg.data)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.objects < 1:
        raise ValueError(f"--objects must be >= 1, got {args.objects}")
    model, datamodule = load_classifier(args.run)
    datamodule.setup(None)
    if args.split not in datamodule.datasets:
        raise ValueError(f"the run's data has no {args.split!r} split; use one of {sorted(datamodule.datasets)}")
    dataset = datamodule.datasets[args.split]
    names = list(datamodule.library.classes)
    right = 0
    shown = min(args.objects, len(dataset))
    for index in range(shown):
        sample = dataset[index]
        inputs = [sample[key][None] for key in model.touch_inputs]  # what the network reads per touch, (1, N, ...)
        with torch.no_grad():
            logits = model.evaluate(*inputs)  # (1, num_classes); averaged over headings where the model asks for it
        probs = logits.softmax(-1)[0]
        top = probs.topk(min(3, len(probs)))
        label = int(sample["label"])
        right += int(top.indices[0]) == label
        guesses = ", ".join(f"{names[int(i)]} {float(p):.0%}" for p, i in zip(top.values, top.indices))
        print(f"{args.split} object {index:3d} ({names[label]}), {sample['tactile'].shape[0]} touches: {guesses}")
    print(f"accuracy: {right}/{shown} = {right / shown:.1%}")
    return 0


if __name__ == "__main__":
    run_cli(main, prog="classify_touches.py")
