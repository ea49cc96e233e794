"""Training loop: runs, checkpoints, resumes bit-identically, is deterministic, checks input."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from nehmo_core.errors import InvalidValueError, ModelFileError, UnknownNameError
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.networks import NetworkSettings, ValueNetwork
from nehmo_core.hjr.systems import Air3D, TwoLinkPair
from nehmo_core.hjr.train import draw_batch, loss_terms, train
from nehmo_core.hjr.train_cli import main, parse_count
from nehmo_core.hjr.train_settings import Schedule, TrainSettings

TINY = TrainSettings(
    variant="bc+sym",
    network=NetworkSettings(width=16, hidden_layers=1),
    samples=20_000,
    batch_size=1_000,
    checkpoint_every=5_000,
    log_every=2,
)


def _weights(run: Path) -> dict[str, torch.Tensor]:
    return load_file(str(run / "model.safetensors"))


def test_tiny_run_writes_files_and_loads(tmp_path: Path) -> None:
    result = train(Air3D(), TINY, tmp_path / "a", progress=False)
    assert result.steps == 20 and result.samples == 20_000
    for name in ("model.safetensors", "model.json", "checkpoint.safetensors", "train_log.csv"):
        assert (tmp_path / "a" / name).exists()
    meta = json.loads((tmp_path / "a" / "model.json").read_text())
    assert meta["system"]["name"] == "air3d" and meta["complete"] and meta["samples"] == 20_000
    lines = (tmp_path / "a" / "train_log.csv").read_text().splitlines()
    assert lines[0].startswith("step,samples,tau_max,loss,dirichlet,pde")
    assert len(lines) == 1 + 10
    vf = load_value_function(tmp_path / "a")
    assert vf.variant == "bc+sym"
    assert np.isfinite(vf.value(1.1, np.zeros((3, 3)))).all()


@pytest.mark.parametrize("lr_schedule", ["constant", "cosine"])
def test_resume_is_identical_to_uninterrupted_run(tmp_path: Path, lr_schedule: str) -> None:
    settings = replace(TINY, lr_schedule=lr_schedule, learning_rate=1e-3)
    train(Air3D(), settings, tmp_path / "full", progress=False)
    partial = train(Air3D(), settings, tmp_path / "resumed", progress=False, stop_after_steps=7)
    assert partial.steps == 7 and not (tmp_path / "resumed" / "model.json").exists()
    train(Air3D(), settings, tmp_path / "resumed", resume=True, progress=False)
    full, resumed = _weights(tmp_path / "full"), _weights(tmp_path / "resumed")
    for key in full:
        assert torch.equal(full[key], resumed[key]), key

    def rows(run: str) -> list[list[str]]:  # every column but the wall time
        lines = (tmp_path / run / "train_log.csv").read_text().splitlines()
        return [line.split(",")[:-1] for line in lines]

    assert rows("resumed") == rows("full")


def test_deterministic_by_seed(tmp_path: Path) -> None:
    settings = replace(TINY, variant="bc", samples=6_000)
    train(TwoLinkPair(), settings, tmp_path / "a", progress=False)
    train(TwoLinkPair(), settings, tmp_path / "b", progress=False)
    train(TwoLinkPair(), replace(settings, seed=1), tmp_path / "c", progress=False)
    a, b, c = _weights(tmp_path / "a"), _weights(tmp_path / "b"), _weights(tmp_path / "c")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_schedule_and_batches() -> None:
    settings = replace(TINY, samples=10_500, pretrain_fraction=0.2, curriculum_fraction=0.5)
    schedule = Schedule.from_settings(settings)
    assert schedule.total_steps == 11 and schedule.pretrain_steps == 2
    assert schedule.batch_size_at(10) == 500
    assert schedule.tau_max(1, 1.1) == 0.0
    assert schedule.tau_max(schedule.pretrain_steps + schedule.curriculum_steps, 1.1) == 1.1
    system = Air3D()
    tau, x, mask = draw_batch(system, settings, schedule, 0)
    assert bool(mask.all()) and float(tau.abs().max()) == 0.0
    tau, x, mask = draw_batch(system, settings, schedule, 5)
    assert bool((tau[mask] == 0).all()) and 0.1 < float(mask.double().mean()) < 0.2
    assert bool(system.in_train(x).all())  # bc+sym folds into X_train
    tau2, x2, _ = draw_batch(system, settings, schedule, 5)
    assert torch.equal(x, x2) and torch.equal(tau, tau2)


def test_learning_rate_schedules() -> None:
    constant = TrainSettings(learning_rate=1e-3)
    assert constant.learning_rate_at(0, 100) == constant.learning_rate_at(99, 100) == 1e-3
    for name in ("cosine", "exponential"):
        s = TrainSettings(learning_rate=1e-3, lr_schedule=name, lr_final_fraction=0.01)
        rates = [s.learning_rate_at(k, 100) for k in range(100)]
        assert rates[0] == pytest.approx(1e-3) and rates[-1] == pytest.approx(1e-5)
        assert all(a >= b for a, b in itertools.pairwise(rates))
    cosine = TrainSettings(learning_rate=1e-3, lr_schedule="cosine", lr_final_fraction=0.01)
    assert cosine.learning_rate_at(50, 101) == pytest.approx(0.505e-3)
    with pytest.raises(UnknownNameError, match="cosine"):
        TrainSettings(lr_schedule="linear")
    with pytest.raises(InvalidValueError, match="lr_final_fraction"):
        TrainSettings(lr_final_fraction=0.0)


def test_presets() -> None:
    assert TrainSettings.preset("cpu_legacy") == TrainSettings()  # the default settings
    cpu = TrainSettings.preset("cpu", variant="bc")
    assert cpu.variant == "bc" and cpu.lr_schedule == "cosine" and cpu.network.width == 64
    assert TrainSettings.preset("authors").network.width == 512


def test_checkpoint_from_before_the_schedule_fields_resumes(tmp_path: Path) -> None:
    """A sidecar without ``lr_schedule``/``lr_final_fraction`` means a constant rate."""
    train(Air3D(), TINY, tmp_path / "old", progress=False, stop_after_steps=5)
    sidecar = tmp_path / "old" / "checkpoint.json"
    meta = json.loads(sidecar.read_text())
    for key in ("lr_schedule", "lr_final_fraction"):
        del meta["settings"][key]
    sidecar.write_text(json.dumps(meta))
    assert train(Air3D(), TINY, tmp_path / "old", resume=True, progress=False).steps == 20


def test_count_parsing() -> None:
    assert parse_count("40M") == 40_000_000
    assert parse_count("500k") == 500_000
    assert parse_count("2e6") == 2_000_000
    assert parse_count("20000") == 20_000
    for bad in ("forty", "-3", "0", "1.5"):
        with pytest.raises(InvalidValueError, match="samples"):
            parse_count(bad)


def test_bad_inputs_raise(tmp_path: Path) -> None:
    with pytest.raises(UnknownNameError, match="deepreach"):
        TrainSettings(variant="sym")
    with pytest.raises(UnknownNameError, match="authors"):
        TrainSettings.preset("gpu")
    with pytest.raises(InvalidValueError, match="batch_size"):
        TrainSettings(batch_size=0)
    with pytest.raises(InvalidValueError, match="curriculum_fraction"):
        TrainSettings(curriculum_fraction=0.0)
    train(Air3D(), replace(TINY, samples=2_000), tmp_path / "run", progress=False)
    with pytest.raises(InvalidValueError, match="out"):
        train(Air3D(), replace(TINY, samples=2_000), tmp_path / "run", progress=False)
    with pytest.raises(ModelFileError, match="settings"):
        train(Air3D(), replace(TINY, samples=4_000), tmp_path / "run", resume=True, progress=False)
    with pytest.raises(ModelFileError, match="two_link"):
        load_value_function(tmp_path / "run", system=TwoLinkPair())
    (tmp_path / "run" / "model.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ModelFileError, match="cannot read"):
        load_value_function(tmp_path / "run")
    with pytest.raises(ModelFileError, match="missing"):
        load_value_function(tmp_path / "nothing.safetensors")


def test_cli_errors_list_valid_choices(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--system", "air4d", "--out", str(tmp_path / "x"), "--no-progress"])
    assert exc.value.code == 2 and "air3d" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["--system", "air3d", "--variant", "sym", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2 and "bc+sym" in capsys.readouterr().err
    args = ["--system", "two_link", "--variant", "deepreach", "--samples", "2k", "--width", "8"]
    assert main([*args, "--batch-size", "1000", "--out", str(tmp_path / "y"), "--no-progress"]) == 0
    assert load_value_function(tmp_path / "y").variant == "deepreach"


def _net_and_batch(
    variant: str, net_seed: int, batch_seed: int
) -> tuple[TwoLinkPair, ValueNetwork, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A small two-link value network and a batch ``(τ, x, boundary mask)`` of 256 states."""
    system = TwoLinkPair()
    net = ValueNetwork(
        system,
        variant,
        NetworkSettings(width=32, hidden_layers=1),
        generator=torch.Generator().manual_seed(net_seed),
    )
    gen = torch.Generator().manual_seed(batch_seed)
    x = system.sample_states(256, gen)
    tau = torch.rand(256, generator=gen) * system.horizon
    return system, net, tau, x, torch.arange(256) >= 200


@pytest.mark.parametrize("variant", ["bc", "bc+sym", "exact"])
def test_fast_pde_loss_equals_full_autograd(variant: str) -> None:
    """The PDE term with a detached boundary gradient equals autograd through V = l̂ + NN."""
    system, net, tau, x, mask = _net_and_batch(variant, 1, 3)
    settings = TrainSettings(variant=variant)
    fast = loss_terms(net, settings, tau, x, mask, pretraining=False)
    t = tau.clone().requires_grad_(True)
    xx = x.clone().requires_grad_(True)
    w, residual = net.forward_with_residual(t, xx)
    dw_dtau, dw_dx = torch.autograd.grad(w.sum(), [t, xx])
    pde = (dw_dtau - system.hamiltonian(xx, dw_dx).clamp(max=0.0)).abs().mean()
    torch.testing.assert_close(fast["pde"], pde, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(fast["dirichlet"], residual[mask].abs().mean())


@pytest.mark.parametrize("pretraining", [False, True])
def test_squared_dirichlet_term(pretraining: bool) -> None:
    """``dirichlet_loss="l2"`` puts the mean squared boundary residual into the loss; the logged
    ``dirichlet`` stays the mean absolute residual, so runs of either kind compare."""
    _, net, tau, x, mask = _net_and_batch("bc", 2, 4)
    l1 = TrainSettings(variant="bc", dirichlet_weight=40.0)
    l2 = replace(l1, dirichlet_loss="l2")
    a = loss_terms(net, l1, tau, x, mask, pretraining=pretraining)
    b = loss_terms(net, l2, tau, x, mask, pretraining=pretraining)
    _, residual = net.forward_with_residual(tau, x)
    on = residual if pretraining else residual[mask]
    torch.testing.assert_close(a["dirichlet"], on.abs().mean())
    torch.testing.assert_close(b["dirichlet"], a["dirichlet"])
    torch.testing.assert_close(b["pde"], a["pde"])
    torch.testing.assert_close(a["loss"], 40.0 * on.abs().mean() + a["pde"])
    torch.testing.assert_close(b["loss"], 40.0 * (on * on).mean() + b["pde"])


@pytest.mark.parametrize("variant", ["bc", "deepreach"])
def test_squared_pde_term(variant: str) -> None:
    """``pde_loss="l2"`` puts the mean squared PDE residual into the loss; the logged ``pde``
    stays the mean absolute residual; pretraining (no PDE term) is unchanged."""
    system, net, tau, x, mask = _net_and_batch(variant, 7, 8)
    l1 = TrainSettings(variant=variant, dirichlet_weight=40.0)
    l2 = replace(l1, pde_loss="l2")
    a = loss_terms(net, l1, tau, x, mask, pretraining=False)
    b = loss_terms(net, l2, tau, x, mask, pretraining=False)
    t = tau.clone().requires_grad_(True)
    xx = x.clone().requires_grad_(True)
    w, _ = net.forward_with_residual(t, xx)
    dw_dtau, dw_dx = torch.autograd.grad(w.sum(), [t, xx])
    r = dw_dtau - system.hamiltonian(xx, dw_dx).clamp(max=0.0)
    torch.testing.assert_close(b["pde"], a["pde"])
    torch.testing.assert_close(a["pde"], r.abs().mean(), rtol=1e-5, atol=1e-6)
    dirichlet_part = a["loss"] - a["pde"]
    torch.testing.assert_close(b["loss"], dirichlet_part + (r * r).mean(), rtol=1e-5, atol=1e-6)
    pre = loss_terms(net, l2, tau, x, mask, pretraining=True)
    torch.testing.assert_close(pre["loss"], loss_terms(net, l1, tau, x, mask, True)["loss"])
    with pytest.raises(UnknownNameError, match="PDE loss"):
        TrainSettings(pde_loss="huber")
    assert TrainSettings().pde_loss == "l1"  # DeepReach's, and every shipped model's


@pytest.mark.parametrize("variant", ["bc", "exact", "deepreach"])
def test_the_gradient_term_adds_the_residual_networks_mean_l1_slope(variant: str) -> None:
    """``gradient_weight`` adds ``weight·mean max(0, ‖∇ₓNN‖₁ − ‖∇ₓl̂‖₁)`` of the residual
    network (bc variants) to the loss and nothing else; DeepReach has no residual network."""
    _, net, tau, x, mask = _net_and_batch(variant, 5, 6)
    plain = TrainSettings(variant=variant)
    steep = replace(plain, gradient_weight=0.5)
    a = loss_terms(net, plain, tau, x, mask, pretraining=False)
    b = loss_terms(net, steep, tau, x, mask, pretraining=False)
    torch.testing.assert_close(b["pde"], a["pde"])
    xx = x.clone().requires_grad_(True)
    (slope,) = torch.autograd.grad(net.siren(net.network_input(tau, xx)).sum(), xx)
    xl = x.clone().requires_grad_(True)
    (boundary,) = torch.autograd.grad(net.boundary_normalized(xl).sum(), xl)
    excess = torch.relu(slope.abs().sum(dim=1) - boundary.abs().sum(dim=1)).mean()
    assert float(excess) > 0.0  # the untrained network is steeper than l̂ somewhere
    extra = 0.0 if variant == "deepreach" else 0.5 * excess
    torch.testing.assert_close(b["loss"], a["loss"] + extra)
    pre = loss_terms(net, steep, tau, x, mask, pretraining=True)
    torch.testing.assert_close(pre["loss"], loss_terms(net, plain, tau, x, mask, True)["loss"])
    with pytest.raises(InvalidValueError, match="gradient_weight"):
        TrainSettings(gradient_weight=-1.0)


def test_the_12d_preset_and_bad_dirichlet_losses() -> None:
    preset = TrainSettings.preset("cpu_12d", variant="bc")
    assert preset.dirichlet_loss == "l2" and preset.network.width == 128
    assert preset.batch_size == 2000 and preset.lr_schedule == "cosine"
    assert TrainSettings().dirichlet_loss == "l1"  # DeepReach's, and every earlier run's
    with pytest.raises(UnknownNameError, match="Dirichlet loss"):
        TrainSettings(dirichlet_loss="huber")


def test_a_sidecar_without_the_dirichlet_loss_means_l1() -> None:
    data = TINY.to_dict()
    del data["dirichlet_loss"]
    data["network"] = TINY.network.to_dict()
    assert TrainSettings.from_dict(data) == TINY


def test_cli_resume_without_a_checkpoint_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--system", "air3d", "--out", str(tmp_path / "new"), "--resume"])
    assert exit_info.value.code == 2
    assert "holds no checkpoint to --resume from" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--lr", "-1", "`--lr` must be > 0"),
        ("--lr-final", "3", "`--lr-final` must lie in (0, 1]"),
        ("--width", "0", "`--width` must be >= 1"),
        ("--batch-size", "0", "`--batch-size` must be > 0"),
        ("--samples", "1.5", "`--samples` must be a positive whole count"),
        ("--gradient-weight", "-1", "`--gradient-weight` must be >= 0"),
        ("--omega0", "0", "`--omega0` must be > 0"),
        ("--pde-loss", "huber", "unknown PDE loss 'huber'. Valid PDE loss names: ['l1', 'l2']"),
    ],
)
def test_cli_errors_name_the_option_typed(
    tmp_path: Path, capsys: pytest.CaptureFixture, option: str, value: str, expected: str
) -> None:
    """A bad value is reported under the option the user typed, not the settings field."""
    with pytest.raises(SystemExit) as exit_info:
        main(["--system", "air3d", "--out", str(tmp_path / "x"), f"{option}={value}"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert expected in err, err
    assert not (tmp_path / "x").exists()
