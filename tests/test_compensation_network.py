"""Training of the compensator network: learning, bit-for-bit reproducibility, resume, early
stopping, and clear errors for bad data."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from msarm.compensation import (
    CheckpointError,
    NetworkConfig,
    Normalizer,
    build_mlp,
    check_finite,
    train_network,
)
from msarm.compensation.pipeline import CompensatorRecipe
from msarm.errors import ConfigError, InputError, MsarmWarning
from msarm.io.config import load_config

D, N_OUT = 6, 4


def _synthetic(n_rows: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Smooth nonlinear targets of scale ~N·m with small noise, from 6 inputs with offsets."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n_rows, D)) * np.array([1.0, 2.0, 0.5, 1.0, 3.0, 1.0]) + 5.0
    u = x - 5.0
    y = np.stack(
        [
            np.sin(u[:, 0]) + 0.3 * u[:, 1] * u[:, 2],
            np.tanh(u[:, 3]) - 0.05 * u[:, 4] ** 2,
            np.cos(u[:, 5]) * u[:, 0],
            0.2 * u[:, 1] - u[:, 2],
        ],
        axis=1,
    )
    return x, 3.0 * y + 0.05 * rng.normal(size=y.shape)


@pytest.fixture(scope="module")
def data():
    x, y = _synthetic(2000, seed=1)
    xv, yv = _synthetic(500, seed=2)
    return x, y, xv, yv


def _states_equal(a, b) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _val_loss(compensator, xv, yv) -> float:
    """Validation MSE in normalised units, computed from the compensator's predictions."""
    norm = compensator.output_normalizer
    z = (compensator.predict(xv) - norm.mean) / norm.std
    return float(np.mean((z - norm.normalize(yv)) ** 2))


FAST = NetworkConfig(batch_size=64, max_epochs=10, patience=50)


def test_training_lowers_validation_loss(data):
    config = NetworkConfig(batch_size=64, max_epochs=25, patience=25)
    seen = []
    result = train_network(*data, config, progress=lambda *args: seen.append(args))
    assert 0.5 < result.initial_val_loss < 2.0  # untrained: about the targets' variance
    assert result.best_val_loss < 0.1 * result.initial_val_loss
    assert result.epochs_run == len(result.history) == len(seen) == 25
    assert [r.epoch for r in result.history] == list(range(1, 26))
    assert seen[-1][:2] == (25, 25)
    assert result.best_val_loss == min(r.val_loss for r in result.history)
    assert result.history[-1].train_loss < result.history[0].train_loss
    assert result.train_time_s > 0
    # the kept weights are those of the best epoch; predictions are in target units (N·m)
    assert _val_loss(result.compensator, data[2], data[3]) == pytest.approx(
        result.best_val_loss, rel=1e-9
    )
    rmse = np.sqrt(np.mean((result.compensator.predict(data[2]) - data[3]) ** 2))
    assert rmse < 0.35 * np.std(data[3])


def test_training_is_reproducible_bit_for_bit(data):
    # the global torch RNG's state does not matter: only config.seed does
    torch.manual_seed(111)
    first = train_network(*data, NetworkConfig(batch_size=64, max_epochs=4, seed=3))
    torch.manual_seed(222)
    second = train_network(*data, NetworkConfig(batch_size=64, max_epochs=4, seed=3))
    other = train_network(*data, NetworkConfig(batch_size=64, max_epochs=4, seed=4))
    assert _states_equal(first.compensator.state_dict(), second.compensator.state_dict())
    assert first.history == second.history
    assert not _states_equal(first.compensator.state_dict(), other.compensator.state_dict())


def test_training_leaves_global_torch_state_alone(data):
    torch.manual_seed(1234)
    expected_draw = torch.rand(3)
    torch.manual_seed(1234)
    threads = torch.get_num_threads()
    deterministic = torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(2)
    try:
        train_network(*data, NetworkConfig(batch_size=256, max_epochs=1, threads=1))
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(torch.rand(3), expected_draw)
    assert torch.are_deterministic_algorithms_enabled() == deterministic


def test_resume_equals_uninterrupted_run(data, tmp_path):
    whole = train_network(*data, FAST, checkpoint_path=tmp_path / "whole.pt")
    half = NetworkConfig(batch_size=64, max_epochs=5, patience=50)
    first = train_network(*data, half, checkpoint_path=tmp_path / "split.pt")
    assert first.epochs_run == 5
    resumed = train_network(*data, FAST, checkpoint_path=tmp_path / "split.pt", resume=True)
    assert resumed.epochs_run == 10
    assert resumed.history == whole.history
    assert resumed.best_epoch == whole.best_epoch
    assert _states_equal(resumed.compensator.state_dict(), whole.compensator.state_dict())
    assert not _states_equal(first.compensator.state_dict(), whole.compensator.state_dict())
    # no temporary files are left next to the checkpoint
    assert sorted(p.name for p in tmp_path.iterdir()) == ["split.pt", "whole.pt"]


def test_resume_after_an_interruption(data, tmp_path):
    whole = train_network(*data, FAST)

    class SimulatedInterruptError(Exception):
        pass

    def stop_at_epoch_5(epoch, max_epochs, train_loss, val_loss):
        if epoch == 5:
            raise SimulatedInterruptError

    path = tmp_path / "state.pt"
    with pytest.raises(SimulatedInterruptError):
        train_network(*data, FAST, checkpoint_path=path, progress=stop_at_epoch_5)
    seen = []
    resumed = train_network(
        *data, FAST, checkpoint_path=path, resume=True, progress=lambda e, *a: seen.append(e)
    )
    assert seen == [6, 7, 8, 9, 10]
    assert resumed.history == whole.history
    assert _states_equal(resumed.compensator.state_dict(), whole.compensator.state_dict())
    # resuming a finished run returns it without training
    again = train_network(*data, FAST, checkpoint_path=path, resume=True, progress=seen.append)
    assert seen == [6, 7, 8, 9, 10]
    assert _states_equal(again.compensator.state_dict(), whole.compensator.state_dict())
    # a shorter training is not the finished longer one (its weights may come from epochs a
    # run of 4 never reaches): refused, so the pipeline starts that round over
    shorter = NetworkConfig(batch_size=64, max_epochs=4, patience=50)
    with pytest.raises(CheckpointError, match="has run 10 epochs, more than max_epochs 4"):
        train_network(*data, shorter, checkpoint_path=path, resume=True)


def test_resume_refuses_other_data_or_config(data, tmp_path, monkeypatch):
    import msarm.compensation.network as network

    path = tmp_path / "state.pt"
    small = NetworkConfig(batch_size=256, max_epochs=1)
    train_network(*data, small, checkpoint_path=path)
    # the same state resumes under the code that wrote it, not under other code
    with monkeypatch.context() as patch:
        patch.setattr(network, "code_fingerprint", lambda scope: "f" * 64)
        with pytest.raises(CheckpointError, match=r"other code \(code fingerprint [0-9a-f]{12}…"):
            train_network(*data, small, checkpoint_path=path, resume=True)
    assert train_network(*data, small, checkpoint_path=path, resume=True).epochs_run == 1
    x, y, xv, yv = data
    y_other = y.copy()
    y_other[0, 0] += 1e-9
    with pytest.raises(CheckpointError, match="other data"):
        train_network(x, y_other, xv, yv, small, checkpoint_path=path, resume=True)
    other = NetworkConfig(batch_size=256, max_epochs=2, learning_rate=1e-2)
    with pytest.raises(CheckpointError, match=r"learning_rate: checkpoint 0\.001, now 0\.01"):
        train_network(*data, other, checkpoint_path=path, resume=True)
    with pytest.raises(CheckpointError, match="file not found"):
        train_network(*data, small, checkpoint_path=tmp_path / "none.pt", resume=True)
    with pytest.raises(InputError, match="checkpoint_path"):
        train_network(*data, small, resume=True)
    path.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="not a readable training checkpoint"):
        train_network(*data, small, checkpoint_path=path, resume=True)


def test_early_stopping_stops_and_keeps_the_best_weights():
    # few noisy samples and a large step: the validation loss improves, then overfitting sets in
    rng = np.random.default_rng(5)
    x, xv = rng.normal(size=(60, D)), rng.normal(size=(300, D))
    y = np.sin(x[:, :N_OUT]) + 0.7 * rng.normal(size=(60, N_OUT))
    yv = np.sin(xv[:, :N_OUT]) + 0.7 * rng.normal(size=(300, N_OUT))
    config = NetworkConfig(
        hidden=(150,), learning_rate=1e-2, batch_size=8, max_epochs=300, patience=4
    )
    result = train_network(x, y, xv, yv, config)
    assert result.stopped_early
    assert result.best_epoch >= 1
    assert result.epochs_run == result.best_epoch + config.patience < config.max_epochs
    losses = [r.val_loss for r in result.history]
    assert min(losses) == result.best_val_loss == losses[result.best_epoch - 1]
    assert all(v >= result.best_val_loss for v in losses[result.best_epoch :])
    assert losses[-1] > result.best_val_loss
    assert _val_loss(result.compensator, xv, yv) == pytest.approx(result.best_val_loss, rel=1e-9)


def test_nan_and_inf_are_reported_with_array_row_and_column(data):
    x, y, xv, yv = data
    bad = x.copy()
    bad[17, 3] = np.nan
    with pytest.raises(InputError, match=r"x_train has 1 non-finite value .*row 17, column 3"):
        train_network(bad, y, xv, yv, FAST)
    names = [f"q.j{i}" for i in range(D)]
    labels = [f"run_7.parquet:{i}" for i in range(len(x))]
    with pytest.raises(InputError, match=r"row 17 \(run_7\.parquet:17\), column 3 \('q\.j3'\)"):
        train_network(bad, y, xv, yv, FAST, column_names=names, train_row_labels=labels)
    bad_target = yv.copy()
    bad_target[4, 2] = np.inf
    bad_target[9, 0] = -np.inf
    message = r"y_val has 2 non-finite values .*row 4, column 2 \('c'\): inf"
    with pytest.raises(InputError, match=message):
        train_network(x, y, xv, bad_target, FAST, target_names=["a", "b", "c", "d"])
    check_finite("ok", x)  # finite: no error


def test_bad_shapes_and_configs_are_refused(data):
    x, y, xv, yv = data
    with pytest.raises(InputError, match="x_train has 2000 rows but y_train has 1999"):
        train_network(x, y[:-1], xv, yv, FAST)
    with pytest.raises(InputError, match="x_val has 5 columns but x_train has 6"):
        train_network(x, y, xv[:, :5], yv, FAST)
    with pytest.raises(InputError, match=r"y_train must have shape"):
        train_network(x, y[:, 0], xv, yv, FAST)
    with pytest.raises(InputError, match="column_names has 2 entries, expected 6"):
        train_network(x, y, xv, yv, FAST, column_names=["a", "b"])
    with pytest.raises(ValueError, match="activation must be one of 'tanh', 'relu'"):
        NetworkConfig(activation="sigmoid")
    with pytest.raises(ValueError, match="patience must be a positive integer"):
        NetworkConfig(patience=0)
    with pytest.raises(ConfigError, match="hidden"):
        load_config({"hidden": [150, -1]}, NetworkConfig)
    assert load_config({"hidden": [64, 32]}, NetworkConfig).hidden == (64, 32)


def test_normalizer_and_network_shape():
    data = np.array([[1.0, 2.0, 7.0], [3.0, 2.0, 9.0], [5.0, 2.0, 11.0]])
    norm = Normalizer.fit(data)
    np.testing.assert_allclose(norm.mean, [3.0, 2.0, 9.0])
    np.testing.assert_allclose(norm.std, [np.sqrt(8 / 3), 1.0, np.sqrt(8 / 3)])  # constant: 1
    z = norm.normalize(data)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(norm.denormalize(z), data, rtol=1e-15)
    assert Normalizer.from_dict(norm.to_dict()) == norm
    net = build_mlp(43, 4, NetworkConfig())
    assert [type(m).__name__ for m in net] == ["Linear", "Tanh", "Linear"]
    assert net[0].weight.shape == (150, 43) and net[0].weight.dtype == torch.float64
    assert net(torch.zeros(7, 43, dtype=torch.float64)).shape == (7, 4)


def test_a_training_that_keeps_the_untrained_weights_says_so():
    # validation targets unrelated to the inputs: no epoch can beat the untrained network by
    # much, and a huge step makes every epoch worse
    x, y = _synthetic(400, seed=3)
    xv, _ = _synthetic(200, seed=4)
    yv = np.random.default_rng(5).normal(size=(200, N_OUT)) * 100.0
    config = NetworkConfig(batch_size=64, max_epochs=2, patience=5, learning_rate=1.0)
    with pytest.warns(MsarmWarning, match="keeps the\\s+initial .random. weights"):
        result = train_network(x, y, xv, yv, config)
    assert result.best_epoch == 0


def test_labels_that_do_not_match_the_array_are_refused():
    """A wrong number of row labels or column names was ignored silently."""
    x = np.array([[1.0, np.nan], [2.0, 3.0]])
    with pytest.raises(InputError, match=r"row_labels: 1 given for 2 of x's"):
        check_finite("x", x, row_labels=["a"])
    with pytest.raises(InputError, match=r"column_names: 3 given for 2 of x's"):
        check_finite("x", x, column_names=["a", "b", "c"])
    with pytest.raises(InputError, match=r"first at row 0 \(a\), column 1 \('q'\)"):
        check_finite("x", x, row_labels=["a", "b"], column_names=["p", "q"])


def test_a_bare_width_and_a_seed_torch_cannot_take_are_refused():
    """``hidden=150`` gave "'int' object is not iterable"; ``seed=2**64`` was accepted (in
    Python and in a recipe) and training failed after the runs were collected with
    "Overflow when unpacking long long"."""
    with pytest.raises(
        InputError, match=r"hidden must be a list of layer sizes, got int 150.*\[150\]"
    ):
        NetworkConfig(hidden=150)
    with pytest.raises(InputError, match="hidden must be a list of layer sizes, got str"):
        NetworkConfig(hidden="150")
    for seed in (2**64, -1, 1.0, True):
        with pytest.raises(InputError, match=r"seed must be an integer in \[0, 2\*\*64 - 1\]"):
            NetworkConfig(seed=seed)
    with pytest.raises(
        ConfigError, match=r"key 'network'.*seed must be an integer in \[0, 2\*\*64"
    ):
        load_config({"network": {"seed": 2**64}}, CompensatorRecipe)
    # the largest seed torch takes still trains
    x, y = _synthetic(40, seed=0)
    config = NetworkConfig(hidden=(4,), max_epochs=1, seed=2**64 - 1)
    assert train_network(x, y, x, y, config).epochs_run == 1
