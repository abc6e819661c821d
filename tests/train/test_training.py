"""Training: the loss goes down, resume is bit-for-bit, checkpoints are safe and atomic."""

import json

import pytest
import torch
from device_params import needs_compiler

from physdrape.model import ModelConfig
from physdrape import checkpoint as ckpt
from physdrape.train.synthetic import SyntheticSource
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

TINY = TrainConfig(
    model=ModelConfig(latent=16, blocks=2, normalizer_accumulations=3, solver="explicit", eta=1e-3, gamma=0.9,
                      max_step=5e-3),
    optim=OptimConfig(steps=8, batch_size=2, lr=3e-3, checkpoint_every=4, log_every=1, seed=3),
)


def trainer(run_dir, config=TINY):
    return Trainer(config, SyntheticSource(), run_dir, progress=False, tensorboard=False)


@pytest.mark.parametrize("solver", ["explicit", "two_level"])
def test_short_training_run_lowers_the_loss(tmp_path, solver):
    # Same two tiny problems every step: the loss on them must fall.
    model = TINY.model if solver == "explicit" else ModelConfig(latent=16, blocks=2, normalizer_accumulations=3)
    config = TrainConfig(model=model, optim=OptimConfig(steps=40, batch_size=2, lr=3e-3, checkpoint_every=40, log_every=5))
    t = trainer(tmp_path, config)
    fixed = t.source.make_batch([11, 12])
    t.source.make_batch = lambda seeds: fixed
    history = t.run()
    first, last = history[0]["loss"], history[-1]["loss"]
    assert last < first - 0.05 * abs(first), f"loss did not fall: {first:.5g} → {last:.5g}"
    # the batch's B2G is measured at the steps the run logs (every 5th), and only there
    logged = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in logged] == list(range(5, 41, 5)) and all(r["b2g_percent"] >= 0 for r in logged)
    assert [r["step"] for r in history if "b2g_percent" in r] == list(range(5, 41, 5))


@needs_compiler
def test_training_with_the_compiled_network_lowers_the_loss(tmp_path):
    """Trainer(compile_network=True): the network's forward and backward compiled
    (`EncodeProcessDecode.compile_network`); the same fixed problems' loss falls."""
    config = TrainConfig(model=TINY.model, optim=OptimConfig(steps=20, batch_size=2, lr=3e-3, checkpoint_every=20,
                                                             log_every=5))
    t = Trainer(config, SyntheticSource(), tmp_path, progress=False, tensorboard=False, compile_network=True)
    fixed = t.source.make_batch([11, 12])
    t.source.make_batch = lambda seeds: fixed
    history = t.run()
    first, last = history[0]["loss"], history[-1]["loss"]
    assert t.model.gnn._compiled is not None  # compiled, not fallen back to eager
    assert last < first - 0.05 * abs(first), f"loss did not fall: {first:.5g} → {last:.5g}"


def test_resume_reproduces_an_uninterrupted_run(tmp_path):
    straight = trainer(tmp_path / "a")
    straight.run()
    interrupted = trainer(tmp_path / "b")
    interrupted.run(until=5)  # killed after step 5; the last checkpoint is step 5's
    (tmp_path / "b" / "latest").write_text("step-00000004\n")  # ... or after step 4's, mid-way to 8

    resumed = trainer(tmp_path / "b")
    resumed.run(resume=True)
    assert resumed.step == straight.step == 8
    for (name, a), (_, b) in zip(straight.model.state_dict().items(), resumed.model.state_dict().items()):
        assert torch.equal(a, b), f"{name} differs after resume"
    steps = [json.loads(line)["step"] for line in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(1, 9))


def test_checkpoint_is_safetensors_and_json_and_loads(tmp_path):
    t = trainer(tmp_path)
    t.run()
    latest = ckpt.latest_checkpoint(tmp_path)
    assert latest.name == "step-00000008"
    assert sorted(p.name for p in latest.iterdir()) == ["config.json", "model.safetensors", "train_state.json", "train_state.safetensors"]
    weights, config = ckpt.read_checkpoint(tmp_path)
    assert config["train"]["model"]["latent"] == 16
    assert not list(tmp_path.glob(".step-*")), "no temporary checkpoint left behind"


def test_broken_checkpoint_pointer_is_explained(tmp_path):
    (tmp_path / "latest").write_text("step-00000099\n")
    with pytest.raises(ckpt.CheckpointError, match="delete .*latest"):
        ckpt.latest_checkpoint(tmp_path)


def test_ship_exports_model_and_training_record(tmp_path):
    from physdrape.train.ship import ship

    trainer(tmp_path / "run").run()
    record = ship(tmp_path / "run", tmp_path / "model", tmp_path / "record", command="physdrape train ...")
    assert sorted(p.name for p in (tmp_path / "model").iterdir()) == ["config.json", "model.safetensors"]
    assert sorted(p.name for p in (tmp_path / "record").iterdir()) == ["loss_curve.png", "metrics.jsonl", "record.json"]
    assert record["step"] == 8 and record["seed"] == 3
    weights, config = ckpt.read_checkpoint(tmp_path / "model")
    assert config["exported_from"] == "step-00000008" and "optim.0.exp_avg" not in weights


def test_init_from_starts_a_fresh_run_from_another_checkpoint(tmp_path):
    from dataclasses import replace

    trainer(tmp_path / "base").run()
    base, _ = ckpt.read_checkpoint(tmp_path / "base")
    tuned = trainer(tmp_path / "tuned", replace(TINY, optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base"))))
    tuned.warm_up_normalizers = lambda: pytest.fail("init_from must keep the checkpoint's input statistics")
    tuned.init_weights(tmp_path / "base")
    for name, value in tuned.model.state_dict().items():
        assert torch.equal(value, base[name]), name
    history = tuned.run()
    assert tuned.step == 1 and len(history) == 1
    wider = replace(TINY, model=replace(TINY.model, latent=8), optim=replace(TINY.optim, init_from=str(tmp_path / "base")))
    with pytest.raises(ckpt.CheckpointError, match="does not fit this run's model"):
        trainer(tmp_path / "wider", wider).run()


def test_init_from_another_solver_kind_keeps_this_runs_eta_and_gamma(tmp_path):
    """An explicit solver's η is a compliance in m/N, a two-level solver's a fraction of a step:
    fine-tuning across kinds takes every weight but those two."""
    from dataclasses import replace

    trainer(tmp_path / "base").run()
    base, _ = ckpt.read_checkpoint(tmp_path / "base")
    two_level = replace(TINY, model=replace(TINY.model, solver="two_level", eta=1.0, gamma=0.98),
                        optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base")))
    tuned = trainer(tmp_path / "tuned", two_level)
    fresh = {k: v.clone() for k, v in tuned.model.state_dict().items()}
    tuned.init_weights(tmp_path / "base")
    for name, value in tuned.model.state_dict().items():
        if name.startswith("solver."):
            assert torch.equal(value, fresh[name]) and not torch.equal(value, base[name]), name
        else:
            assert torch.equal(value, base[name]), name


def test_init_from_with_a_zero_output_keeps_the_decoders_last_layer_at_zero(tmp_path):
    """zero_init_output + init_from: the checkpoint's features, a silent network at the start
    (the drape is the solver's and handler's alone), and learning from there."""
    from dataclasses import replace

    trainer(tmp_path / "base").run()
    base, _ = ckpt.read_checkpoint(tmp_path / "base")
    silent = replace(TINY, model=replace(TINY.model, zero_init_output=True),
                     optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base")))
    tuned = trainer(tmp_path / "tuned", silent)
    tuned.init_weights(tmp_path / "base")
    last = f"gnn.decoder.{len(tuned.model.gnn.decoder) - 1}."
    for name, value in tuned.model.state_dict().items():
        if name.startswith(last):
            assert not value.any() and base[name].any(), name
        else:
            assert torch.equal(value, base[name]), name
    batch = tuned.source.make_batch([11, 12]).drape
    tuned.model.eval()
    torch.testing.assert_close(tuned.model(batch).x, tuned.model.physics_only(batch).x, rtol=0, atol=0)


def test_init_from_a_shallower_checkpoint_keeps_the_added_mesh_blocks_at_the_identity(tmp_path):
    """model.mesh_blocks on top of a checkpoint without them: its weights, and the new blocks as
    they start (silent), so the fine-tune starts from the checkpoint's drape."""
    from dataclasses import replace

    trainer(tmp_path / "base").run()
    base, _ = ckpt.read_checkpoint(tmp_path / "base")
    deeper = replace(TINY, model=replace(TINY.model, mesh_blocks=1),
                     optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base")))
    tuned = trainer(tmp_path / "tuned", deeper)
    fresh = {k: v.clone() for k, v in tuned.model.state_dict().items()}
    tuned.init_weights(tmp_path / "base")
    added = f"gnn.blocks.{TINY.model.blocks}."
    for name, value in tuned.model.state_dict().items():
        assert torch.equal(value, fresh[name] if name.startswith(added) else base[name]), name
    assert any(k.startswith(added) for k in fresh)
    longer = replace(TINY, model=replace(TINY.model, blocks=TINY.model.blocks + 1),
                     optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base")))
    with pytest.raises(ckpt.CheckpointError, match="does not fit this run's model"):
        trainer(tmp_path / "longer", longer).init_weights(tmp_path / "base")


def test_init_from_a_checkpoint_without_summaries_keeps_them_at_zero(tmp_path):
    """model.global_context on top of a checkpoint without it: its weights, and the garments'
    summaries as they start (silent), so the fine-tune starts from the checkpoint's drape."""
    from dataclasses import replace

    trainer(tmp_path / "base").run()
    base, _ = ckpt.read_checkpoint(tmp_path / "base")
    summarised = replace(TINY, model=replace(TINY.model, global_context=True),
                         optim=replace(TINY.optim, steps=1, init_from=str(tmp_path / "base")))
    tuned = trainer(tmp_path / "tuned", summarised)
    fresh = {k: v.clone() for k, v in tuned.model.state_dict().items()}
    tuned.init_weights(tmp_path / "base")
    for name, value in tuned.model.state_dict().items():
        assert torch.equal(value, fresh[name] if name.startswith("gnn.global_mlps.") else base[name]), name
    assert any(k.startswith("gnn.global_mlps.") for k in fresh)
