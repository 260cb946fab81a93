"""The ``replay:`` section of a scenario file (see ``smarts.core.spec.replay``), strictly validated.

Only what the file itself can say is checked here (formats, choices, ranges); ids and times are
checked against the recording when the env is built (``smarts.replay.plan_replay``), so reading a
scenario never parses a large dataset.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, PlainValidator

from smarts.core.schema import Schema
from smarts.core.spec.replay import COORDINATES, REACTIVE_MODES, REPLAY_FORMATS, ReplaySpec

MAX_REACTIVE_DISTANCE = 1000.0


def _vehicle_id(value: Any) -> str:
    """Dataset ids are numbers in NGSIM and Waymo: ``12`` and ``"12"`` name the same vehicle."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise ValueError(f"expected a recorded vehicle id (a string or an integer), got {type(value).__name__}")
    text = str(value).strip()
    if not text:
        raise ValueError("expected a non-empty vehicle id")
    return text


def _path(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a file or folder path")
    return value


def _scenario_id(value: Any) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)) or not str(value).strip():
        raise ValueError("expected a scenario id or a 0-based record index")
    return str(value).strip()


VehicleId = Annotated[str, PlainValidator(_vehicle_id, json_schema_input_type=str | int)]
ScenarioId = Annotated[str, PlainValidator(_scenario_id, json_schema_input_type=str | int)]
Seconds = Annotated[float, Field(ge=0, le=1e7, allow_inf_nan=False)]


class ReplayFile(Schema):
    """Recorded traffic from a dataset, replayed around the agents."""

    format: Literal[REPLAY_FORMATS] = Field(description="ngsim, argoverse2 or waymo.")  # type: ignore[valid-type]
    path: Annotated[str, PlainValidator(_path, json_schema_input_type=str)] = Field(
        description="NGSIM CSV, Argoverse 2 scenario folder or Waymo TFRecord, relative to the scenario file."
    )
    start: Seconds | None = Field(
        None, description="s after the recording's first frame; null: 0, or when the taken-over vehicles are there."
    )
    duration: Annotated[float, Field(gt=0, le=1e7, allow_inf_nan=False)] | None = Field(
        None, description="s of recording replayed; null: to its end."
    )
    vehicles: list[VehicleId] | None = Field(None, description="Recorded ids to replay; null: all.")
    take_over: dict[Annotated[str, Field(min_length=1)], VehicleId] = Field(
        default_factory=dict, description="agent id -> recorded vehicle id the agent drives."
    )
    reactive: Literal[REACTIVE_MODES] = Field(  # type: ignore[valid-type]
        "off",
        description="off; interaction: a vehicle an agent comes near switches to the traffic model; always.",
    )
    reactive_distance: Annotated[float, Field(gt=0, le=MAX_REACTIVE_DISTANCE, allow_inf_nan=False)] = Field(
        10.0, description="m between centres at which an agent interacts with a recorded vehicle."
    )
    coordinates: Literal[COORDINATES] = Field("local", description="NGSIM: Local_X/Y or Global_X/Y.")  # type: ignore[valid-type]
    swap_xy: bool = False
    flip_y: bool = False
    offset: Annotated[list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [0.0, 0.0], description="[x, y] m added after swapping and flipping."
    )
    scenario: ScenarioId | None = Field(
        None,
        description="Waymo: scenario id or record index in the file (null: the first); NGSIM: the site "
        "(Location column) to keep from the data portal's file of every site.",
    )

    def to_spec(self) -> ReplaySpec:
        return ReplaySpec(
            format=self.format,
            path=self.path,
            start=self.start,
            duration=self.duration,
            vehicles=None if self.vehicles is None else list(self.vehicles),
            take_over=dict(self.take_over),
            reactive=self.reactive,
            reactive_distance=self.reactive_distance,
            coordinates=self.coordinates,
            swap_xy=self.swap_xy,
            flip_y=self.flip_y,
            offset=(float(self.offset[0]), float(self.offset[1])),
            scenario=self.scenario,
        )


def replay_to_dict(replay: ReplaySpec) -> dict[str, Any]:
    """The section as plain data that ``ReplayFile`` reads back into an equal spec."""
    out: dict[str, Any] = {"format": replay.format, "path": replay.path}
    defaults = ReplaySpec(format=replay.format, path=replay.path)
    for key in ("start", "duration", "vehicles", "reactive", "reactive_distance", "coordinates", "swap_xy",
                "flip_y", "scenario"):  # fmt: skip
        value = getattr(replay, key)
        if value != getattr(defaults, key):
            out[key] = list(value) if isinstance(value, list) else value
    if replay.take_over:
        out["take_over"] = dict(replay.take_over)
    if tuple(replay.offset) != (0.0, 0.0):
        out["offset"] = list(replay.offset)
    return out
