"""Spec models and error types sit in core: one class each, reachable from the packages that use them."""

from __future__ import annotations

import pickle
import subprocess
import sys

import pydantic
import pytest

import smarts.core.errors as errors
import smarts.core.spec as core_spec
from smarts.scenario import ScenarioSpec, load_scenario, map_path, read_scenario, replace, scenario_to_dict


def test_old_import_paths_give_the_same_classes():
    import smarts.benchmark.metrics as metrics
    import smarts.comms.config as comms_config
    import smarts.dynamics as dynamics
    import smarts.maps as maps
    import smarts.scenario as scenario
    import smarts.scenario.errors as scenario_errors
    import smarts.sensors as sensors
    import smarts.sensors.interface as sensors_interface
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
    for module in (scenario, sensors_interface, comms_config):
        for name in set(module.__all__) & set(core_spec.__all__):
            assert getattr(module, name) is getattr(core_spec, name), (module.__name__, name)
    assert scenario.ScenarioSpec is core_spec.ScenarioSpec


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


def test_a_read_scenario_is_the_one_frozen_spec_class():
    spec = load_scenario("straight_2lane_cruise")
    assert type(spec) is core_spec.ScenarioSpec is ScenarioSpec
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        spec.seed = 3
    assert read_scenario(scenario_to_dict(spec), base_dir=spec.base_dir) == spec
    again = replace(spec, seed=spec.seed + 1)
    assert type(again) is ScenarioSpec and again.seed == spec.seed + 1 and again != spec
    assert (again.source, again.base_dir) == (spec.source, spec.base_dir) and map_path(again) == map_path(spec)
    with pytest.raises(errors.ScenarioError, match=r"ScenarioSpec: seed: input should be greater than or equal to 0"):
        replace(spec, seed=-1)  # a changed spec is validated again
    with pytest.raises(TypeError, match="no field seeds"):
        replace(spec, seeds=1)


def test_a_spec_built_in_code_equals_the_read_one_and_the_env_takes_it_as_it_is():
    from smarts.env.assembly import as_spec

    spec = load_scenario("straight_2lane_cruise")
    built = ScenarioSpec(**{name: getattr(spec, name) for name in ScenarioSpec.model_fields})
    assert built == spec and built.source == "<dict>"  # where it was read from is not part of the scenario
    assert as_spec(spec) is spec and as_spec("straight_2lane_cruise") == spec


def test_core_spec_and_errors_load_without_the_layers_above():
    code = (
        "import sys, smarts.core.spec, smarts.core.errors, smarts.sensors.interface, smarts.comms.config\n"
        "above = ('smarts.scenario', 'smarts.traffic', 'smarts.dynamics', 'smarts.env', 'smarts.maps')\n"
        "print(sorted(m for m in sys.modules if m.startswith(above)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
