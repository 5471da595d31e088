"""The trained compensator: save/load round trip, refusal of files that do not fit (with the
reason), and the numpy fast path against torch."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from msarm.compensation import (
    CheckpointError,
    Compensator,
    FastCompensator,
    NetworkConfig,
    Normalizer,
    build_mlp,
    train_network,
)
from msarm.compensation.features import FeatureSpec
from msarm.errors import InputError

D, N_OUT = 43, 4
SHA = "a" * 64
OTHER_SHA = "b" * 64
SPEC = {"groups": ("q", "qdot", "tension"), "window": 5, "filter": {"cutoff_hz": 20.0}}


def _compensator(
    hidden: tuple[int, ...] = (150,), activation: str = "tanh", seed: int = 0
) -> Compensator:
    """A compensator with random weights and non-trivial normalizers (offsets, scales)."""
    rng = np.random.default_rng(seed)
    config = NetworkConfig(hidden=hidden, activation=activation)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = build_mlp(D, N_OUT, config)
    x = rng.normal(size=(200, D)) * rng.uniform(0.01, 10.0, size=D) + rng.normal(size=D) * 5
    y = rng.normal(size=(200, N_OUT)) * np.array([0.5, 2.0, 1.0, 0.1]) + 0.3
    metadata = {"model_sha256": SHA, "feature_spec": SPEC, "metrics": {"rmse": [0.1, 0.2]}}
    return Compensator(
        net.state_dict(), Normalizer.fit(x), Normalizer.fit(y), config, metadata=metadata
    )


@pytest.fixture(scope="module")
def compensator() -> Compensator:
    return _compensator()


def _inputs(compensator: Compensator, rows: int, seed: int) -> np.ndarray:
    """Random inputs spread like the data the normalizer was fitted on."""
    rng = np.random.default_rng(seed)
    norm = compensator.input_normalizer
    return norm.mean + norm.std * rng.normal(size=(rows, D)) * 1.5


def test_save_load_round_trip(compensator, tmp_path):
    path = compensator.save(tmp_path / "sub" / "comp.pt")
    assert [p.name for p in path.parent.iterdir()] == ["comp.pt"]  # no temporary file left
    loaded = Compensator.load(path, expected_model_sha256=SHA, expected_feature_spec=SPEC)
    x = _inputs(compensator, 64, seed=1)
    np.testing.assert_array_equal(loaded.predict(x), compensator.predict(x))
    assert loaded.metadata == compensator.metadata
    assert loaded.metadata["feature_spec"]["groups"] == ("q", "qdot", "tension")
    assert loaded.config == compensator.config
    assert loaded.input_normalizer == compensator.input_normalizer
    assert loaded.output_normalizer == compensator.output_normalizer
    # a spec read back from YAML (lists instead of tuples, ints for floats) is the same spec
    yaml_spec = {"groups": ["q", "qdot", "tension"], "window": 5, "filter": {"cutoff_hz": 20}}
    Compensator.load(path, expected_feature_spec=yaml_spec)
    # overwriting an existing file
    compensator.save(path)
    assert [p.name for p in path.parent.iterdir()] == ["comp.pt"]


def test_behaviour_hash_follows_what_the_compensator_does_not_its_training_record(tmp_path):
    base = _compensator()
    value = base.behaviour_sha256()
    assert len(value) == 64 and value == _compensator().behaviour_sha256()  # deterministic
    loaded = Compensator.load(base.save(tmp_path / "comp.pt"))
    assert loaded.behaviour_sha256() == value  # a round trip keeps it
    # the training's own record (losses, epochs, times) changes nothing it does
    timed = _compensator()
    timed.metadata["training"] = {"collect_time_s": 14.5, "history": [[1, 0.3, 0.4]]}
    assert timed.behaviour_sha256() == value
    timed.metadata["training"]["collect_time_s"] = 0.2
    assert timed.behaviour_sha256() == value
    # nor where the recipe put its files (the same network trained into another folder)
    placed = _compensator()
    placed.metadata["recipe"] = {"checkpoint": "a/c.pt", "data": {"folder": "a", "n_runs": 14}}
    moved = _compensator()
    moved.metadata["recipe"] = {"checkpoint": "b/c.pt", "data": {"folder": "b", "n_runs": 14}}
    assert placed.behaviour_sha256() == moved.behaviour_sha256()
    moved.metadata["recipe"]["data"]["n_runs"] = 10  # the rest of the recipe does
    assert placed.behaviour_sha256() != moved.behaviour_sha256()
    # a weight, a normaliser, the config or the rest of the metadata does
    nudged = _compensator()
    name = next(iter(nudged._module.state_dict()))
    with torch.no_grad():
        nudged._module.state_dict()[name].view(-1)[0] += 1e-12
    assert nudged.behaviour_sha256() != value
    assert _compensator(seed=1).behaviour_sha256() != value
    assert _compensator(activation="relu").behaviour_sha256() != value
    staged = _compensator()
    staged.metadata["sheath"] = {"parameters": {"mu": 0.1256}}
    assert staged.behaviour_sha256() != value


def test_predict_shapes_and_bad_inputs(compensator):
    x = _inputs(compensator, 5, seed=2)
    batch = compensator.predict(x)
    assert batch.shape == (5, N_OUT) and batch.dtype == np.float64
    single = compensator.predict(x[3])
    assert single.shape == (N_OUT,)
    np.testing.assert_allclose(single, batch[3], rtol=0, atol=1e-12)
    with pytest.raises(InputError, match=r"expects shape \(43,\) or \(N, 43\), got \(42,\)"):
        compensator.predict(x[0, :42])
    x[2, 7] = np.nan
    with pytest.raises(InputError, match="row 2, column 7"):
        compensator.predict(x)


def test_load_refuses_another_robot_model(compensator, tmp_path):
    path = compensator.save(tmp_path / "comp.pt")
    with pytest.raises(CheckpointError, match="another robot model") as info:
        Compensator.load(path, expected_model_sha256=OTHER_SHA)
    assert SHA in str(info.value) and OTHER_SHA in str(info.value)
    no_sha = _compensator()
    del no_sha.metadata["model_sha256"]
    with pytest.raises(CheckpointError, match="no 'model_sha256'"):
        Compensator.load(no_sha.save(tmp_path / "nosha.pt"), expected_model_sha256=SHA)


def test_load_refuses_weights_that_are_not_finite(compensator, tmp_path):
    """A NaN weight was refused only at the first call, as an "overflow" of |x| = 1 with no
    file named; now at load, naming the file and the tensor."""
    saved = torch.load(compensator.save(tmp_path / "comp.pt"), weights_only=True)
    name = next(iter(saved["state_dict"]))
    saved["state_dict"][name][0, 0] = float("nan")
    torch.save(saved, tmp_path / "nan.pt")
    with pytest.raises(
        CheckpointError,
        match=rf"nan\.pt: the network's weights '{re.escape(name)}' hold 1 value\(s\) that "
        "are not finite",
    ):
        Compensator.load(tmp_path / "nan.pt", expected_model_sha256=SHA)


def test_load_refuses_another_feature_spec(compensator, tmp_path):
    path = compensator.save(tmp_path / "comp.pt")
    other = {"groups": ("q", "qdot"), "window": 10, "filter": {"cutoff_hz": 20.0}, "extra": 1}
    with pytest.raises(CheckpointError, match="another feature spec") as info:
        Compensator.load(path, expected_model_sha256=SHA, expected_feature_spec=other)
    message = str(info.value)
    assert "3 differences" in message
    assert "feature_spec.window: compensator 5, in use 10" in message
    assert "feature_spec.groups: compensator ['q', 'qdot', 'tension'], in use ['q', 'qdot']" in (
        message
    )
    assert "feature_spec.extra only in the spec in use" in message
    assert "cutoff_hz" not in message


def test_load_refuses_missing_corrupt_and_foreign_files(compensator, tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        Compensator.load(tmp_path / "missing.pt")
    good = compensator.save(tmp_path / "good.pt").read_bytes()
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(good[: len(good) // 2])
    with pytest.raises(CheckpointError, match="not a readable compensator file"):
        Compensator.load(corrupt)
    corrupt.write_bytes(np.random.default_rng(0).bytes(4000))
    with pytest.raises(CheckpointError, match="not a readable compensator file"):
        Compensator.load(corrupt)
    # another kind of file: told what to give instead, not torch's advice on weights_only
    table = tmp_path / "log.parquet"
    table.write_bytes(b"PAR1" + bytes(100) + b"PAR1")
    with pytest.raises(CheckpointError, match=r"runs/compensator/compensator.pt") as caught:
        Compensator.load(table)
    assert "weights_only" not in str(caught.value)

    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(
        CheckpointError, match=r"not an msarm compensator checkpoint .a dict with no 'format' tag"
    ):
        Compensator.load(other)
    plain = compensator.to_dict()
    del plain["state_dict"], plain["metadata"]
    torch.save(plain, other)
    with pytest.raises(CheckpointError, match="missing keys: state_dict, metadata"):
        Compensator.load(other)
    plain = compensator.to_dict()
    plain["format_version"] = 99
    torch.save(plain, other)
    with pytest.raises(CheckpointError, match="format version 99"):
        Compensator.load(other)
    plain = compensator.to_dict()
    plain["state_dict"]["0.weight"] = torch.zeros(150, 42, dtype=torch.float64)
    torch.save(plain, other)
    with pytest.raises(CheckpointError, match=r"do not fit a network 43 -> .150. -> 4"):
        Compensator.load(other)
    plain = compensator.to_dict()
    plain["config"]["activation"] = "sigmoid"
    torch.save(plain, other)
    with pytest.raises(CheckpointError, match=r"invalid network config.*activation"):
        Compensator.load(other)


class _Arbitrary:
    def __init__(self, value: int) -> None:
        self.value = value


def test_load_never_unpickles_arbitrary_classes(compensator, tmp_path):
    plain = compensator.to_dict()
    plain["metadata"] = {"object": _Arbitrary(1)}
    path = tmp_path / "pickled.pt"
    torch.save(plain, path)
    with pytest.raises(CheckpointError, match="not a readable compensator file"):
        Compensator.load(path)
    with pytest.raises(InputError, match=r"metadata\.object: a _Arbitrary cannot be stored"):
        Compensator(
            compensator.state_dict(),
            compensator.input_normalizer,
            compensator.output_normalizer,
            compensator.config,
            metadata={"object": _Arbitrary(1)},
        )


def test_training_checkpoint_is_not_a_compensator(tmp_path):
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(50, 3)), rng.normal(size=(50, 2))
    state = tmp_path / "state.pt"
    result = train_network(
        x, y, x, y, NetworkConfig(hidden=(8,), max_epochs=1), checkpoint_path=state,
        metadata={"model_sha256": SHA},
    )  # fmt: skip
    assert result.compensator.metadata == {"model_sha256": SHA}
    with pytest.raises(CheckpointError, match="this is a training checkpoint"):
        Compensator.load(state)


@pytest.mark.parametrize(
    ("hidden", "activation"), [((150,), "tanh"), ((150,), "relu"), ((32, 16), "tanh"), ((), "tanh")]
)
def test_fast_path_equals_torch(hidden, activation):
    compensator = _compensator(hidden, activation, seed=3)
    fast = FastCompensator(compensator)
    x = _inputs(compensator, 200, seed=4)
    expected = compensator.predict(x)
    assert np.max(np.abs(expected)) > 0.1  # outputs are not trivially small
    for row in range(0, 200, 7):
        np.testing.assert_allclose(fast(x[row]), expected[row], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast(x), expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast.predict_batch(x), expected, rtol=0, atol=1e-6)
    # a returned array is the caller's own: the next call does not overwrite it
    first = fast(x[0])
    fast(x[1])
    np.testing.assert_allclose(first, expected[0], rtol=0, atol=1e-6)
    # lists and float32 arrays go through the checked path
    np.testing.assert_allclose(fast(list(x[5])), expected[5], rtol=0, atol=1e-6)
    out = np.empty(N_OUT)
    assert fast(x[6], out=out) is out
    np.testing.assert_allclose(out, expected[6], rtol=0, atol=1e-6)


def test_fast_path_refuses_bad_inputs(compensator):
    fast = FastCompensator(compensator)
    x = _inputs(compensator, 1, seed=5)[0]
    for bad in (np.nan, np.inf, -np.inf):
        x_bad = x.copy()
        x_bad[11] = bad
        with pytest.raises(InputError, match="row 0, column 11"):
            fast(x_bad)
    with pytest.raises(InputError, match=r"expects shape \(43,\) or \(N, 43\), got \(44,\)"):
        fast(np.zeros(44))
    with pytest.raises(InputError, match="out must be a float64 array of shape"):
        fast(x, out=np.empty(3))
    with pytest.raises(InputError, match="only supported for one sample"):
        fast(np.zeros((2, D)), out=np.empty(N_OUT))
    # text, None and complex values: named (a bare numpy error, or the imaginary part dropped)
    for predict in (fast, fast.predict_batch, compensator.predict):
        with pytest.raises(InputError, match="x: expected features as real numbers, got 'abc'"):
            predict("abc")
        with pytest.raises(InputError, match="x: expected features as real numbers, got None"):
            predict(None)
        with pytest.raises(InputError, match="got complex values"):
            predict(np.zeros((2, D)) + 1j)
    with pytest.raises(InputError, match="got complex values"):  # one sample: the fast path's
        fast(np.zeros(D) + 1j)


def test_load_takes_the_feature_spec_in_use(tmp_path):
    """``expected_feature_spec=FeatureSpec()`` gave "'FeatureSpec' object is not iterable"."""
    spec = FeatureSpec()
    made = _compensator()
    made.metadata["feature_spec"] = spec.as_dict()
    path = made.save(tmp_path / "comp.pt")
    assert Compensator.load(path, expected_feature_spec=spec).input_dim == D
    assert Compensator.load(path, expected_feature_spec=spec.as_dict()).input_dim == D
    other = FeatureSpec(drum_radius=0.004)
    with pytest.raises(
        CheckpointError, match=r"feature_spec\.drum_radius: compensator 0\.003, in use 0\.004"
    ):
        Compensator.load(path, expected_feature_spec=other)
    with pytest.raises(CheckpointError, match="drum_radius"):
        made.check_compatible(expected_feature_spec=other)
    with pytest.raises(
        InputError, match=r"expected_feature_spec must be a FeatureSpec or a dict .* got int 3"
    ):
        Compensator.load(path, expected_feature_spec=3)


def test_ragged_features_are_refused_with_the_shape_expected(compensator):
    """A ragged list gave numpy's "inhomogeneous shape" ValueError (np.iscomplexobj ran
    outside the conversion's check)."""
    fast = FastCompensator(compensator)
    row = [0.0] * D
    for predict, shape in (
        (fast, rf"\({D},\) or \(N, {D}\)"),
        (compensator.predict, rf"\({D},\) or \(N, {D}\)"),
        (fast.predict_batch, rf"\(N, {D}\)"),
    ):
        for ragged in ([row, row[:-1]], [1.0, [2.0, 3.0]]):
            with pytest.raises(
                InputError,
                match=rf"x: expected features as an array of shape {shape}, got a ragged",
            ):
                predict(ragged)
