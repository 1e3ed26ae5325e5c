"""The real Hydra configs: every experiment composes and instantiates; train.py and eval.py run end to end."""

from __future__ import annotations

from pathlib import Path

import hydra
import pytest
import torch
from conftest import CONFIGS, compose_config
from omegaconf import OmegaConf, open_dict

EXPERIMENTS = sorted(p.stem for p in (CONFIGS / "experiment").glob("*.yaml"))
RECON_ABLATIONS = {"full", "no_gap", "no_direction", "region_1x1", "region_5x5", "single_stage", "visual_only"}


def test_every_ablation_has_an_experiment_config() -> None:
    assert RECON_ABLATIONS | {"tactile_only", "classify", "smoke"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_composes_and_instantiates(experiment: str, tmp_path: Path) -> None:
    cfg = compose_config("train", [f"experiment={experiment}"], tmp_path)
    assert cfg.experiment_name == experiment
    assert cfg.model.name == experiment
    datamodule = hydra.utils.instantiate(cfg.data)
    model = hydra.utils.instantiate(cfg.model)
    if experiment.startswith("classify"):
        assert type(datamodule).__name__ == "ClassificationDataModule"
        assert model.num_touches == cfg.data.num_touches == model.net.num_touches
        if experiment == "classify_touch_set":  # one set model for every N, tested at 1..10 touches
            assert type(model.net).__name__ == "TouchSetClassifier" and model.eval_touches == [1, 2, 4, 6, 8, 10]
        if experiment != "classify":  # the cls_paper_cpu runs: the paper's 1,500 test images, read once per process
            assert datamodule.dataset_kwargs["eval_draws"] == 10 and datamodule.dataset_kwargs["memory_cache"]
        train, test = datamodule.make_dataset("train"), datamodule.make_dataset("test")
        # the paper's classifier sees the pad's own 31 pixels, or them upsampled towards the paper's 224 on load
        size = {"classify": 64, "classify_paper_cpu_upsampled": 112}.get(experiment, 31)
        assert train.tactile_size == test.tactile_size == (size, size)
        assert train.redraw_touches and not test.redraw_touches  # fresh touches per training epoch only
        assert not train.rotate_touches  # the orientation augmentation is off until measured to help
        if experiment.startswith("classify_contact"):  # beyond the paper: the touches as 3D contact patches
            assert type(model.net).__name__ == "ContactCloudClassifier" and model.controls == ["other"]
            assert train.patches and test.patches and train.rotate_pose and not test.redraw_touches
            assert "patch_points" in model.touch_inputs
            assert model.net.points_per_touch == (1 if experiment == "classify_contact_point" else 64)
            assert (model.net.trunk is not None) == (experiment == "classify_contact_cloud_images")
            assert (model.net.patch_mlp is not None) == (experiment == "classify_contact_patches")
        return
    assert type(datamodule).__name__ == "ReconstructionDataModule"
    net = model.net
    # beyond the paper: precise BatchNorm statistics before each validation, the model and data otherwise the paper's
    assert ("precise_bn" in cfg.callbacks) == experiment.endswith("_precise_bn")
    expected_mode = {
        "visual_only": "visual_only",
        "visual_only_precise_bn": "visual_only",
        "tactile_only": "tactile_only",
        "touch_geometry": "touch_geometry",
        "touch_geometry_no_rim": "touch_geometry",
        "touch_geometry_view_pass": "touch_geometry",
        "touch_residual": "touch_geometry",
        "touch_cascade": "touch_geometry",
        "chart_based": "chart_based",
        "chart_based_predicted": "chart_based",
        "chart_based_visual": "chart_based_visual",
        "chart_based_tactile": "chart_based_tactile",
    }.get(experiment, "fusion")
    assert net.mode == expected_mode
    if expected_mode.startswith("chart_based"):  # the Chart-based method (Smith et al. 2020): its own graph and loss
        assert net.reads_patches and type(model.criterion).__name__ == "ChartLoss"
        assert net.touch_chart == ("predicted" if experiment == "chart_based_predicted" else "patch")
        assert (net.touch_predictor is not None) == (experiment == "chart_based_predicted")
        assert (net.visual is None) == (not net.chart_deformer.use_image) == (experiment == "chart_based_tactile")
        assert model.hparams.min_touches == (1 if experiment == "chart_based_tactile" else 0)
        assert model.hparams.lr_scales is None and model.modality == {
            "chart_based_visual": "visual",
            "chart_based_tactile": "tactile",
        }.get(experiment, "tactile_visual")
        return
    if expected_mode == "visual_only":
        assert net.fusion is None and net.tactile is None
        return
    if expected_mode == "touch_geometry":  # beyond the paper: no tactile branch, the deformer reads the patches
        assert net.reads_patches and not hasattr(net, "tactile") and model.hparams.patch_loss_weight > 0
        residual = type(net.deformer).__name__ in ("TouchResidualDeformer", "TouchCascadeDeformer")
        assert residual == (experiment in ("touch_residual", "touch_cascade"))
        # the residual's visual path, and the view pass, train the touch-free answer on every sample
        assert net.view_pass == (experiment == "touch_geometry_view_pass")
        assert model.hparams.min_touches == (1 if residual or net.view_pass else 0)
        # the patches' contact test: relative to each touch's deepest push only where the experiment drops the rim
        assert cfg.data.patch_min_push_fraction == (0.4 if experiment == "touch_geometry_no_rim" else 0.0)
        return
    fusion = net.fusion
    assert fusion.use_gap == (experiment != "no_gap")
    assert fusion.use_direction == (experiment != "no_direction")
    assert fusion.region == {"region_1x1": 1, "region_5x5": 5}.get(experiment, 3)
    assert len(fusion.pairs) == (4 if experiment == "single_stage" else 16)
    assert fusion.touch_depth == (experiment == "touch_depth")


def test_paper_preset_optimizer_and_schedule(tmp_path: Path) -> None:
    cfg = compose_config("train", ["experiment=full"], tmp_path)
    model = hydra.utils.instantiate(cfg.model)
    opt = model.optimizer_factory(params=[torch.nn.Parameter(torch.zeros(1))])
    assert isinstance(opt, torch.optim.AdamW) and opt.param_groups[0]["lr"] == pytest.approx(2e-5)
    sched = model.scheduler_factory(optimizer=opt)
    assert isinstance(sched, torch.optim.lr_scheduler.CosineAnnealingLR) and sched.T_max == 50
    assert cfg.trainer.max_epochs == 50


def _synthetic(cfg, tmp_path: Path) -> None:
    """Keep the composed real config, swap the data for the test-only synthetic datamodule."""
    with open_dict(cfg):
        cfg.data = OmegaConf.create({"_target_": "synthetic.SyntheticReconDataModule", "batch_size": 2, "n": 4})
        cfg.model.metric_points = 200
        cfg.model.eval_touches = [2, 5]


def test_fast_dev_run_train_prints_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from train import train

    cfg = compose_config("train", ["experiment=smoke", "+trainer.fast_dev_run=true"], tmp_path)
    _synthetic(cfg, tmp_path)
    with open_dict(cfg):
        cfg.model.export = False
    out = train(cfg)
    res = out["result"]
    # smoke also tests with test-time touch refinement (its own Table 3 row) and the touch controls
    modes = {
        "visual",
        "tv@2",
        "tv@5",
        "tv@2+refine",
        "tv@5+refine",
        "tv@2:other",
        "tv@2:blank",
        "tv@5:other",
        "tv@5:blank",
    }
    assert res["name"] == "smoke" and set(res["modes"]) == modes
    assert (tmp_path / "metrics.json").is_file()
    assert (tmp_path / "tables" / "table3.csv").is_file() and (tmp_path / "tables" / "table4.md").is_file()
    printed = capsys.readouterr().out
    assert "Table 3" in printed and "Table 4" in printed and "Ours (smoke, tiny data)" in printed
    assert "Ours (smoke, tiny data) + touch refinement" in printed
    assert "What the touches did in this run" in printed and "Another object's 5 touches" in printed  # make demo


def test_precise_bn_recalibrates_before_the_validation_of_a_real_fit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import tvrecon.train.bn_recalibrate as bn
    from train import train

    calls: list[tuple[int, int]] = []
    real = bn.recalibrate_batchnorm

    def spy(model, batches, forward, num_batches):  # noqa: ANN001, ANN202
        layers = real(model, batches, forward, num_batches)
        calls.append((num_batches, layers))
        return layers

    monkeypatch.setattr(bn, "recalibrate_batchnorm", spy)
    cfg = compose_config("train", ["experiment=smoke", "+trainer.fast_dev_run=true"], tmp_path)
    _synthetic(cfg, tmp_path)
    precise = compose_config("train", ["experiment=full_precise_bn"], tmp_path / "cfg").callbacks.precise_bn
    with open_dict(cfg):
        cfg.model.export = False
        cfg.callbacks.precise_bn = precise
    train(cfg)
    # one validation in a fast_dev_run fit, none in the test that follows; the fusion model's BatchNorms all recomputed
    assert len(calls) == 1 and calls[0][0] == 20 and calls[0][1] > 20


@pytest.mark.slow
def test_train_checkpoint_then_eval_writes_tables(tmp_path: Path) -> None:
    from eval import evaluate
    from train import train

    run = tmp_path / "run"
    overrides = [
        "experiment=smoke", "trainer.max_epochs=1", "+trainer.limit_train_batches=1", "+trainer.limit_val_batches=1",
        "+trainer.limit_test_batches=1", "model.render_every_n_epochs=0", "model.export=false", "logger=csv",
    ]  # fmt: skip
    cfg = compose_config("train", overrides, run)
    _synthetic(cfg, tmp_path)
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")  # what hydra.main writes for every run
    out = train(cfg)
    best = Path(out["best_ckpt"])
    assert best.is_file() and (run / "checkpoints" / "last.ckpt").is_file()
    assert (run / "loss_curves.png").is_file()

    overrides = [f"run_dir={run}", "eval_touches=[2]", "export=true", "fusion_share_batches=1"]
    result = evaluate(compose_config("eval", overrides, tmp_path / "eval"))
    [res] = result["results"]
    assert res["name"] == "smoke" and set(res["modes"]) == {"visual", "tv@2"}
    share = res["fusion_share"]  # the Agg blocks' addition against the visual features, per stage
    assert share["touches"] == 2 and share["samples"] > 0 and set(share["stages"]) == {"0", "1", "2", "3"}
    assert res["checkpoint"] == str(best)  # the best checkpoint is preferred over last.ckpt
    tables = tmp_path / "eval" / "tables"
    assert {p.name for p in tables.iterdir()} >= {"table3.md", "table3.csv", "table4.md", "table4.csv", "tables.md"}
    assert "Ours (smoke, tiny data)" in (tables / "table3.md").read_text()
    run_out = tmp_path / "eval" / "00_run"
    assert (run_out / "metrics.json").is_file()
    objs = sorted(p.name for p in (run_out / "meshes").glob("*.obj"))
    assert objs == [f"{c}_{m}.obj" for c in ("bottle", "bowl", "can") for m in ("tv2", "visual")]
    assert (run_out / "renders" / "test_bottle_tv2.png").is_file()

    # split=val scores the validation split (choosing an evaluation setting without the test split): metrics only
    val = evaluate(compose_config("eval", [f"run_dir={run}", "split=val"], tmp_path / "eval_val"))
    [vres] = val["results"]
    assert vres["task"] == "validation" and vres["checkpoint"] == str(best)
    assert vres["val"]["val/chamfer"] > 0 and "val/chamfer" in val["tables"]
    assert not (tmp_path / "eval_val" / "tables").exists()
    # bn_recalibrate_batches: the same checkpoint scored with its BatchNorm statistics recomputed on training batches
    recal = evaluate(
        compose_config(
            "eval",
            [f"run_dir={run}", "split=val", "bn_recalibrate_batches=2", "bn_recalibrate_touches=max"],
            tmp_path / "eval_val_bn",
        )
    )
    [rres] = recal["results"]
    assert rres["bn_recalibrated"]["batches"] == 2 and rres["bn_recalibrated"]["touches"] == "max"
    assert rres["bn_recalibrated"]["layers"] > 0
    shift = rres["bn_recalibrated"]["shift"]  # per group of layers (net.visual, net.tactile, ...)
    assert sum(g["layers"] for g in shift.values()) == rres["bn_recalibrated"]["layers"]
    assert all(g["mean_shift"] >= 0 and g["std_ratio"] >= 1 for g in shift.values())
    worst = rres["bn_recalibrated"]["worst_layers"]  # the layers whose stored statistics are the furthest off
    assert 0 < len(worst) <= 5 and all(g["layer"].startswith("net.") for g in worst)

    def off(g: dict) -> float:
        return max(g["mean_shift"], g["std_ratio"])

    assert off(worst[0]) == max(off(g) for g in shift.values())  # the furthest first
    assert [off(g) for g in worst] == sorted((off(g) for g in worst), reverse=True)
    assert rres["val"]["val/chamfer"] > 0 and rres["val"]["val/chamfer"] != vres["val"]["val/chamfer"]
    assert "bn_recalibrated" not in vres


def test_bn_recalibrate_options_are_checked(tmp_path: Path) -> None:
    from eval import recalibrate_statistics

    def cfg(*overrides: str):  # noqa: ANN202
        return compose_config("eval", ["ckpt_path=x.ckpt", *overrides], tmp_path)

    classifier = torch.nn.Linear(2, 2)  # no training_mask: not a reconstruction model
    assert recalibrate_statistics(classifier, None, cfg()) == {}  # off by default: nothing is asked of the model
    with pytest.raises(ValueError, match="bn_recalibrate_batches must be >= 0"):
        recalibrate_statistics(classifier, None, cfg("bn_recalibrate_batches=-1"))
    with pytest.raises(ValueError, match="for reconstruction runs"):
        recalibrate_statistics(classifier, None, cfg("bn_recalibrate_batches=2"))
    classifier.training_mask = classifier.full_mask = lambda batch: None
    with pytest.raises(ValueError, match="bn_recalibrate_touches must be 'train' or 'max'"):
        recalibrate_statistics(classifier, None, cfg("bn_recalibrate_batches=2", "bn_recalibrate_touches=all"))


def test_eval_split_must_be_test_or_val(tmp_path: Path) -> None:
    from eval import eval_split

    assert eval_split(compose_config("eval", ["ckpt_path=x.ckpt"], tmp_path)) == "test"
    with pytest.raises(ValueError, match="split must be 'test' or 'val'"):
        eval_split(compose_config("eval", ["ckpt_path=x.ckpt", "split=train"], tmp_path))


def test_missing_checkpoint_names_path_and_command(tmp_path: Path) -> None:
    from eval import evaluate

    missing = tmp_path / "nope" / "last.ckpt"
    cfg = compose_config("eval", [f"ckpt_path={missing}", "torch_threads=2"], tmp_path)
    with pytest.raises(FileNotFoundError, match=r"checkpoint .*nope/last\.ckpt does not exist.*python train\.py"):
        evaluate(cfg)
    assert torch.get_num_threads() == 2  # eval.py's torch_threads, like train.py's (the fixture restores it)
    (tmp_path / "empty").mkdir()
    cfg = compose_config("eval", [f"run_dir={tmp_path / 'empty'}"], tmp_path)
    with pytest.raises(FileNotFoundError, match=r"no checkpoints/\*\.ckpt below .*empty.*experiment=smoke"):
        evaluate(cfg)
    cfg = compose_config("eval", [], tmp_path)
    with pytest.raises(ValueError, match="exactly one of ckpt_path"):
        evaluate(cfg)


def test_resume_from_missing_checkpoint_is_a_clear_error(tmp_path: Path) -> None:
    from train import train

    cfg = compose_config("train", ["experiment=smoke", f"ckpt_path={tmp_path / 'gone.ckpt'}"], tmp_path)
    _synthetic(cfg, tmp_path)
    with pytest.raises(FileNotFoundError, match=r"ckpt_path=.*gone\.ckpt does not exist"):
        train(cfg)


@pytest.mark.parametrize(
    "overrides",
    [["debug=fdr"], ["debug=overfit"], ["debug=limit"], ["trainer=gpu"], ["trainer=ddp", "trainer.devices=4"],
     ["trainer=ddp_sim"], ["logger=csv"], ["logger=tensorboard"]],
)  # fmt: skip
def test_debug_trainer_logger_groups_compose(overrides: list[str], tmp_path: Path) -> None:
    cfg = compose_config("train", ["experiment=smoke", *overrides], tmp_path)
    if overrides[0].startswith("debug"):
        assert cfg.task_name == "debug" and cfg.logger is None and cfg.callbacks is None
        assert cfg.trainer.get("fast_dev_run", False) == (overrides[0] == "debug=fdr")
    if overrides[0] == "trainer=ddp":
        assert cfg.trainer.strategy.startswith("ddp") and cfg.trainer.devices == 4 and cfg.trainer.sync_batchnorm
    if overrides[0].startswith("logger="):
        assert list(cfg.logger) == [overrides[0].split("=")[1]]


def test_hparams_search_defines_a_basic_sweep(tmp_path: Path) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        cfg = compose("train", ["hparams_search=lr_wd"], return_hydra_config=True)
    assert cfg.hydra.sweeper._target_.endswith("BasicSweeper")
    assert set(cfg.hydra.sweeper.params) == {"model.optimizer.lr", "model.optimizer.weight_decay"}
    assert cfg.optimized_metric == "val/chamfer"


def test_classify_experiment_trains_and_prints_table2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from train import train

    overrides = ["experiment=classify", "+trainer.fast_dev_run=true", "model.num_touches=2", "model.net.num_classes=3"]
    cfg = compose_config("train", overrides, tmp_path)
    with open_dict(cfg):
        cfg.data = OmegaConf.create(
            {"_target_": "synthetic.SyntheticClassificationDataModule", "num_touches": 2, "batch_size": 3}
        )
    out = train(cfg)
    assert out["result"]["task"] == "classification" and set(out["result"]["accuracy"]) == {"2"}
    printed = capsys.readouterr().out
    assert "Table 2" in printed and "2-touch" in printed
    assert (tmp_path / "tables" / "table2.csv").read_text().splitlines()[0].startswith("Model,1-touch,2-touch")


def test_run_folders_of_runs_started_in_one_second_differ() -> None:
    """Two runs (or sweeps) started in the same second must not share a folder: they would write their checkpoints
    over each other's. The folder time ends in microseconds."""
    from datetime import datetime

    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        cfg = compose("train", [], return_hydra_config=True)
    for node in (cfg.hydra.run, cfg.hydra.sweep):
        raw = OmegaConf.to_container(node, resolve=False)["dir"]
        pattern = raw.split("${now:")[-1].split("}")[0]  # the time part of the folder name
        a, b = datetime(2026, 1, 1, 3, 38, 20, 123), datetime(2026, 1, 1, 3, 38, 20, 957)  # one second, two starts
        assert a.strftime(pattern) != b.strftime(pattern), raw
