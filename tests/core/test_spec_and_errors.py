"""Spec datatypes and error types sit in core: one class each, reachable from the old import paths."""

from __future__ import annotations

import dataclasses
import pickle
import subprocess
import sys

import pytest

import smarts.core.errors as errors
import smarts.core.spec as core_spec
from smarts.scenario import ScenarioSpec, load_scenario


def test_old_import_paths_give_the_same_classes():
    import smarts.benchmark.metrics as metrics
    import smarts.dynamics as dynamics
    import smarts.maps as maps
    import smarts.scenario as scenario
    import smarts.scenario.errors as scenario_errors
    import smarts.scenario.spec as scenario_spec
    import smarts.scenario.traffic as scenario_traffic
    import smarts.sensors as sensors
    from smarts.core.errors import AgentSetupError
    from smarts.core.policies import NoResolverError
    from smarts.dynamics.action_spaces import ActionError
    from smarts.env.sb3_vec_env import WorkerError
    from smarts.sensors.interface import InterfaceError

    assert scenario.ScenarioError is scenario_errors.ScenarioError is errors.ScenarioError
    assert scenario.NetconvertError is errors.NetconvertError
    assert ActionError is dynamics.ActionError is errors.ActionError
    assert InterfaceError is sensors.InterfaceError is errors.InterfaceError
    assert metrics.LogError is errors.LogError
    assert metrics.MetricParamsError is metrics.params.MetricParamsError is errors.MetricParamsError
    assert WorkerError is errors.WorkerError
    assert AgentSetupError is errors.AgentSetupError
    assert NoResolverError is errors.NoResolverError
    assert maps.MapError is errors.MapError and maps.NoRouteError is errors.NoRouteError
    for name in scenario_traffic.__all__:
        assert getattr(scenario_traffic, name) is getattr(core_spec, name)
    for name in set(scenario.__all__) & set(core_spec.__all__) - {"ScenarioSpec"}:
        assert getattr(scenario, name) is getattr(core_spec, name), name
    for name in set(scenario_spec.__all__) & set(core_spec.__all__) - {"ScenarioSpec"}:
        assert getattr(scenario_spec, name) is getattr(core_spec, name), name
    assert issubclass(scenario.ScenarioSpec, core_spec.ScenarioSpec)


def test_error_types_keep_their_bases():
    value_errors = ("ScenarioError", "ActionError", "AgentSetupError", "NoResolverError", "InterfaceError")
    for name in (*value_errors, "LogError", "MetricParamsError", "MapError"):
        assert issubclass(getattr(errors, name), ValueError), name
    assert issubclass(errors.NoRouteError, errors.MapError)
    assert issubclass(errors.NetconvertError, RuntimeError)
    assert issubclass(errors.WorkerError, RuntimeError)
    err = pickle.loads(pickle.dumps(errors.LogError("bad", source="f.npz", agent="a", column="x")))
    assert (str(err), err.agent, err.column) == ("f.npz: agent 'a': column 'x': bad", "a", "x")
    assert errors.ActionError("m", ["a"]).agent_ids == ["a"]
    with pytest.raises(AttributeError):
        errors.NoSuchError  # noqa: B018


def test_a_read_scenario_is_the_core_dataclass_with_yaml_methods():
    spec = load_scenario("straight_2lane_cruise")
    assert isinstance(spec, core_spec.ScenarioSpec)
    assert type(spec) is ScenarioSpec
    assert dataclasses.fields(spec) == dataclasses.fields(core_spec.ScenarioSpec)
    assert ScenarioSpec.from_dict(spec.to_dict(), base_dir=spec.base_dir) == spec
    again = dataclasses.replace(spec, seed=spec.seed + 1)
    assert type(again) is ScenarioSpec and again.map_path() == spec.map_path()


def test_the_env_takes_a_plain_core_spec():
    from smarts.env.assembly import as_spec

    spec = load_scenario("straight_2lane_cruise")
    plain = core_spec.ScenarioSpec(**{f.name: getattr(spec, f.name) for f in dataclasses.fields(spec)})
    assert type(plain) is core_spec.ScenarioSpec
    built = as_spec(plain)
    assert type(built) is ScenarioSpec and built == spec and built.base_dir == spec.base_dir
    assert as_spec(spec) is spec


def test_core_spec_and_errors_load_without_the_layers_above():
    code = (
        "import sys, smarts.core.spec, smarts.core.errors, smarts.sensors.interface, smarts.comms.config\n"
        "above = ('smarts.scenario', 'smarts.traffic', 'smarts.dynamics', 'smarts.env', 'smarts.maps')\n"
        "print(sorted(m for m in sys.modules if m.startswith(above)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
