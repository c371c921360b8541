"""The route agents' model file: save/load round trip, files from before the format tag, one-line errors."""

import io

import numpy as np
import polars as pl
import pytest
import torch

from models.urban.col_marl import RouteAgentsQ, numpy_params
from models.urban.policy_file import FORMAT, PolicyFileError, load_policies, load_policy, policy_bytes

AGENTS = ["r0:car", "r0:heavy", "r1:car"]


@pytest.fixture
def params():
    return numpy_params(RouteAgentsQ(len(AGENTS), 6, torch.Generator().manual_seed(0)))


def _write(path, blob) -> str:
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    path.write_bytes(buffer.getvalue())
    return str(path)


def test_round_trip_keeps_weights_agents_guard_and_provenance(tmp_path, params):
    path = tmp_path / "p.pt"
    path.write_bytes(policy_bytes(params, AGENTS, True, variant="col", scenario="sc1", seed=3, episodes=50, gradient_steps=None))
    policy = load_policy(path)
    assert policy["format"] == FORMAT and policy["agents"] == AGENTS and policy["leader_guard"] is True
    assert {k: policy[k] for k in ("variant", "scenario", "seed", "episodes", "gradient_steps")} == {
        "variant": "col", "scenario": "sc1", "seed": 3, "episodes": 50, "gradient_steps": None}
    assert policy["params"].keys() == params.keys()
    assert all(isinstance(policy["params"][k], np.ndarray) and policy["params"][k].dtype == np.float32 for k in params)
    assert all(np.array_equal(policy["params"][k], params[k]) for k in params)


def test_files_from_before_the_format_tag_still_load(tmp_path, params):
    # exactly what urban_training wrote before the tag: numpy weights, no "format"; the oldest also had no leader_guard
    old = {"params": params, "agents": AGENTS, "variant": "col", "scenario": "sc1", "seed": 0, "episodes": 50, "gradient_steps": None}
    guarded, oldest = _write(tmp_path / "a.pt", {**old, "leader_guard": True}), _write(tmp_path / "b.pt", old)
    training = pl.DataFrame({"scenario": ["sc1"] * 3, "method": ["col_marl", "col_marl", "i_marl"], "seed": [1, 0, 0],
                             "model_path": [guarded, guarded, oldest]})
    policies = load_policies(training)
    assert policies.keys() == {("sc1", "col_marl"), ("sc1", "i_marl")} and list(policies["sc1", "col_marl"]) == [0, 1]  # seeds in order
    agents, weights, guard = policies["sc1", "col_marl"][1]
    assert agents == AGENTS and guard is True and all(np.array_equal(weights[k], params[k]) for k in params)
    assert policies["sc1", "i_marl"][0][2] is False


def _error(path) -> str:
    with pytest.raises(PolicyFileError) as info:
        load_policy(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_a_missing_file_is_one_line(tmp_path):
    assert "not found" in _error(tmp_path / "gone.pt")


def test_a_file_that_is_not_a_policy_file_is_one_line(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    assert "not an urban policy file (UnpicklingError)" in _error(tmp_path / "junk.pt")
    # a torch file, but weights only (e.g. a state dict) or a tagged file that lost its route agents
    assert "not an urban policy file (no route agents" in _error(_write(tmp_path / "sd.pt", {"w1": torch.zeros(2)}))
    assert "not an urban policy file (no route agents" in _error(_write(tmp_path / "t.pt", {"format": FORMAT, "params": {}}))
    # weights that are not a name -> tensor mapping (it raised AttributeError: 'list' object has no attribute 'items')
    assert "not an urban policy file (no route agents" in _error(_write(tmp_path / "w.pt", {"format": FORMAT, "params": [torch.zeros(2)], "agents": []}))
    assert "not an urban policy file" in _error(_write(tmp_path / "l.pt", [torch.zeros(2)]))


def test_a_file_of_another_format_is_one_line(tmp_path, params):
    newer = _write(tmp_path / "v2.pt", {**torch.load(io.BytesIO(policy_bytes(params, AGENTS, True))), "format": "trafficlearn.urban_policy.v2"})
    assert f"format 'trafficlearn.urban_policy.v2', this trafficlearn reads {FORMAT}" in _error(newer)
    assert "format 'trafficlearn.trajectory.v1'" in _error(_write(tmp_path / "traj.pt", {"format": "trafficlearn.trajectory.v1", "phases": []}))
