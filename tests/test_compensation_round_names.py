"""The name a training round gives its runs: what the round's network feeds forward."""

from __future__ import annotations

import numpy as np
import torch

from msarm.compensation.checkpoint import Compensator
from msarm.compensation.features import FeatureSpec
from msarm.compensation.network import NetworkConfig, Normalizer, build_mlp
from msarm.compensation.pipeline import _weights_hash


def _compensator(config=None, out_std=(1.0, 2.0), spec=None) -> Compensator:
    config = config or NetworkConfig(hidden=(4,))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        weights = build_mlp(3, 2, config).state_dict()
    return Compensator(
        weights,
        Normalizer(np.zeros(3), np.ones(3)),
        Normalizer(np.zeros(2), np.array(out_std)),
        config,
        metadata={"feature_spec": (spec or FeatureSpec()).as_dict()},
    )


def test_a_round_name_tells_networks_that_feed_forward_differently():
    """Same weights, other normaliser, activation or features: another dtau, another name
    (until 2026-11-29 the name hashed the weights alone, and a round reused runs collected
    with another network: a training that kept its seeded initial weights after a change
    of target or features)."""
    base = _compensator()
    assert _weights_hash(_compensator()) == _weights_hash(base)
    # the training settings do not change what it feeds forward: its runs are reused
    assert _weights_hash(_compensator(NetworkConfig(hidden=(4,), patience=5))) == _weights_hash(
        base
    )
    x = np.array([0.3, -0.2, 0.5])
    for other in (
        _compensator(out_std=(1.0, 3.0)),
        _compensator(NetworkConfig(hidden=(4,), activation="relu")),
    ):
        assert not np.array_equal(other.predict(x), base.predict(x))
        assert _weights_hash(other) != _weights_hash(base)
    # the same network on other inputs (the features are computed otherwise)
    assert _weights_hash(_compensator(spec=FeatureSpec(sign_joint_speed=0.1))) != _weights_hash(
        base
    )
