"""The shared training loop: resume gives the same weights, bad runs stop clearly."""
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from wmthesis.training import ConfigMismatch, NonFiniteLoss, train, trained_seconds


@dataclass(frozen=True)
class Cfg:
    lr: float = 0.05


TRUE_W = torch.tensor([[2.0, -1.0, 0.5]])


def problem(nan_at=None):
    torch.manual_seed(0)
    model = torch.nn.Linear(3, 1)
    optimiser = torch.optim.Adam(model.parameters(), lr=0.05)
    calls = {"n": 0}

    def sample(split, rng):
        x = torch.as_tensor(rng.normal(size=(16, 3)), dtype=torch.float32)
        noise = 0.01 * torch.randn(16, 1)  # the torch RNG is part of the resumable state
        return {"x": x, "y": x @ TRUE_W.T + noise}

    def loss_fn(batch):
        calls["n"] += 1
        loss = ((model(batch["x"]) - batch["y"]) ** 2).mean()
        return {"loss": loss * (torch.nan if nan_at and model.training and calls["n"] >= nan_at else 1.0)}

    return model, optimiser, sample, loss_fn


def test_training_converges_and_keeps_the_best_weights(tmp_path):
    model, optimiser, sample, loss_fn = problem()
    history = train(model, optimiser, loss_fn, sample, steps=300, checkpoint=tmp_path / "ck.pt", config=Cfg(),
                    eval_every=50, progress=False)
    assert [h["step"] for h in history] == [50, 100, 150, 200, 250, 300]
    assert history[-1]["val_loss"] < 1e-3 < history[0]["val_loss"]
    assert torch.allclose(model.weight, TRUE_W, atol=0.02)
    assert (tmp_path / "ck.best.pt").exists()


def test_resumed_run_reaches_the_same_weights(tmp_path):
    model, optimiser, sample, loss_fn = problem()
    train(model, optimiser, loss_fn, sample, steps=40, checkpoint=tmp_path / "a.pt", config=Cfg(),
          eval_every=10, progress=False)
    straight = model.weight.detach().clone()

    model, optimiser, sample, loss_fn = problem()
    train(model, optimiser, loss_fn, sample, steps=20, checkpoint=tmp_path / "b.pt", config=Cfg(),
          eval_every=10, progress=False)
    model, optimiser, sample, loss_fn = problem()  # a fresh process would start like this
    history = train(model, optimiser, loss_fn, sample, steps=40, checkpoint=tmp_path / "b.pt", config=Cfg(),
                    eval_every=10, progress=False)
    assert [h["step"] for h in history] == [10, 20, 30, 40]
    assert torch.equal(model.weight.detach(), straight)


def test_a_checkpoint_keeps_the_seconds_trained_over_every_sitting(tmp_path, monkeypatch):
    """A run cut off and resumed reports the time of both sittings (the results table's minutes a
    seed), not its last sitting's alone; a cached run adds nothing."""
    clock = {"now": 0.0}
    monkeypatch.setattr("wmthesis.training.time.perf_counter", lambda: clock["now"])
    model, optimiser, sample, loss_fn = problem()

    def slow(batch):  # every update takes 2 seconds of the clock
        clock["now"] += 2.0
        return loss_fn(batch)

    assert trained_seconds(tmp_path / "c.pt") == 0.0  # nothing trained yet
    train(model, optimiser, slow, sample, steps=20, checkpoint=tmp_path / "c.pt", config=Cfg(), eval_every=10,
          eval_batches=1, progress=False)
    first = trained_seconds(tmp_path / "c.pt")
    assert first == 2.0 * (20 + 2)  # 20 updates and 2 evaluations of 1 batch
    clock["now"] += 1000.0  # the machine was off
    train(model, optimiser, slow, sample, steps=40, checkpoint=tmp_path / "c.pt", config=Cfg(), eval_every=10,
          eval_batches=1, progress=False)
    assert trained_seconds(tmp_path / "c.pt") == 2 * first
    train(model, optimiser, slow, sample, steps=40, checkpoint=tmp_path / "c.pt", config=Cfg(), eval_every=10,
          eval_batches=1, progress=False)  # finished: nothing trains, nothing is added
    assert trained_seconds(tmp_path / "c.pt") == 2 * first


def test_early_stopping_with_patience(tmp_path):
    model, optimiser, sample, loss_fn = problem()
    history = train(model, optimiser, loss_fn, sample, steps=10_000, checkpoint=tmp_path / "ck.pt", config=Cfg(),
                    eval_every=50, patience=2, progress=False)
    assert history[-1]["step"] < 10_000
    best = min(h["val_loss"] for h in history)
    assert history[-1]["val_loss"] >= best and history[-2]["val_loss"] >= best


def test_changed_config_refuses_to_resume(tmp_path):
    model, optimiser, sample, loss_fn = problem()
    train(model, optimiser, loss_fn, sample, steps=10, checkpoint=tmp_path / "ck.pt", config=Cfg(),
          eval_every=10, progress=False)
    with pytest.raises(ConfigMismatch, match=r"ck.pt.*'lr': \(0.05, 0.1\)"):
        train(model, optimiser, loss_fn, sample, steps=20, checkpoint=tmp_path / "ck.pt", config=Cfg(lr=0.1),
              eval_every=10, progress=False)


def test_nan_loss_names_the_step_and_keeps_the_last_checkpoint(tmp_path):
    model, optimiser, sample, loss_fn = problem(nan_at=None)
    path = tmp_path / "ck.pt"
    train(model, optimiser, loss_fn, sample, steps=10, checkpoint=path, config=Cfg(), eval_every=10, progress=False)
    saved = torch.load(path, weights_only=False)["model"]["weight"].clone()
    model, optimiser, sample, loss_fn = problem(nan_at=8)  # 8th loss call: step 8 of the resumed run's steps
    with pytest.raises(NonFiniteLoss, match=r"update 18 .*kept at"):
        train(model, optimiser, loss_fn, sample, steps=30, checkpoint=path, config=Cfg(), eval_every=10,
              progress=False)
    assert torch.equal(torch.load(path, weights_only=False)["model"]["weight"], saved)


def test_corrupt_checkpoint_is_reported(tmp_path):
    path = tmp_path / "ck.pt"
    path.write_bytes(b"not a checkpoint")
    model, optimiser, sample, loss_fn = problem()
    with pytest.raises(ValueError, match="cannot read checkpoint"):
        train(model, optimiser, loss_fn, sample, steps=10, checkpoint=path, config=Cfg(), progress=False)
    assert np.isfinite(model.weight.detach().numpy()).all()
