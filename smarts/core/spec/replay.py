"""The ``replay:`` section of a scenario: which recorded dataset to replay, and how.

A frozen, validated model every layer reads; ``smarts.replay`` loads the recording and drives its
vehicles. Only what the file itself can say is checked here (formats, choices, ranges); ids and
times are checked against the recording when the env is built (``smarts.replay.plan_replay``), so
reading a scenario never parses a large dataset.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, PlainValidator

from smarts.core.spec.base import AsList, AsTuple, Spec

REPLAY_FORMATS = ("ngsim", "argoverse2", "waymo")
REACTIVE_MODES = ("off", "interaction", "always")
"""``off``: recorded vehicles always follow their tracks; ``interaction``: one switches to the
built-in traffic model (IDM/MOBIL) the first time an agent comes within ``reactive_distance``;
``always``: every recorded vehicle is driven by the traffic model from the moment it enters."""
COORDINATES = ("local", "global")
"""NGSIM's column pairs: Local_X/Local_Y (metres along and across the study area) or
Global_X/Global_Y (state plane coordinates)."""
REPLAY_MAP = "replay"
"""A scenario's ``map`` naming the dataset's own map (Argoverse 2's map JSON, Waymo's map features)."""
MAX_COORDINATE = 1.0e8
"""m (or feet) beyond which a coordinate is not a position on Earth in any projection."""
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
Metres = Annotated[float, Field(allow_inf_nan=False)]


class ReplaySpec(Spec):
    """Recorded traffic from a dataset, replayed around the agents."""

    format: Literal[REPLAY_FORMATS] = Field(description="ngsim, argoverse2 or waymo.")  # type: ignore[valid-type]
    path: Annotated[str, PlainValidator(_path, json_schema_input_type=str)] = Field(
        description="NGSIM CSV, Argoverse 2 scenario folder or Waymo TFRecord, relative to the scenario file's folder."
    )
    start: Seconds | None = Field(
        None,
        description="s after the recording's first frame at which the episode starts; null: 0, or the entry of "
        "the latest-entering taken-over vehicle.",
    )
    duration: Annotated[float, Field(gt=0, le=1e7, allow_inf_nan=False)] | None = Field(
        None, description="s of recording replayed from start; null: to the end of the recording."
    )
    vehicles: list[VehicleId] | None = Field(None, description="Recorded ids to replay; null: all.")
    take_over: dict[Annotated[str, Field(min_length=1)], VehicleId] = Field(
        default_factory=dict,
        description="agent id -> recorded vehicle id: the agent starts in that vehicle's state at start and its "
        "goal is the vehicle's last recorded position.",
    )
    reactive: Literal[REACTIVE_MODES] = Field(  # type: ignore[valid-type]
        "off",
        description="off; interaction: a vehicle an agent comes near switches to the traffic model; always.",
    )
    reactive_distance: Annotated[float, Field(gt=0, le=MAX_REACTIVE_DISTANCE, allow_inf_nan=False)] = Field(
        10.0, description="m between an agent's centre and a recorded vehicle's at which they interact."
    )
    coordinates: Literal[COORDINATES] = Field("local", description="NGSIM: Local_X/Y or Global_X/Y.")  # type: ignore[valid-type]
    swap_xy: bool = False
    flip_y: bool = False
    offset: Annotated[list[Metres], Field(min_length=2, max_length=2), AsList, AsTuple] = Field(
        (0.0, 0.0), description="[x, y] m added to every position after swapping and flipping."
    )
    scenario: ScenarioId | None = Field(
        None,
        description="Waymo: scenario id or record index in the file (null: the first); NGSIM: the site "
        "(Location column) to keep from the data portal's file of every site.",
    )
