"""Every shipped YAML (configs, the scenario library, the README's example) reads into the same
values as when the snapshot was recorded, whatever classes hold them.

The snapshot (``spec_snapshot.json``) holds one sha256 per file of a canonical plain-data dump of
what its loader returns: mappings with sorted keys, lists, and scalars tagged with their type
(a float is its exact ``repr``), paths relative to the repository. On a mismatch the test prints
the full dump, so the difference can be read. To record again (only when a change of values is
intended): ``python tests/scenario/test_spec_snapshot.py --record``.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
SNAPSHOT = Path(__file__).with_name("spec_snapshot.json")
README_BLOCK = re.compile(r"```yaml\n(name: my_left_turn\n.*?)```", re.S)


def canonical(value: Any, tmp: Path | None = None) -> Any:
    """``value`` as plain JSON data independent of the classes holding it."""
    if value is None or isinstance(value, (bool, str)):
        return _text(value, tmp) if isinstance(value, str) else value
    if isinstance(value, enum.Enum):
        return canonical(value.value, tmp)
    if type(value).__module__ == "numpy" and hasattr(value, "item"):
        return canonical(value.item(), tmp)
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return {"float": repr(value)}
    if isinstance(value, Path):
        return {"path": _text(str(value), tmp)}
    if isinstance(value, Mapping):
        return {str(k): canonical(v, tmp) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [canonical(v, tmp) for v in value]
    return {name: canonical(getattr(value, name), tmp) for name in sorted(_field_names(value))}


def _field_names(value: Any) -> list[str]:
    if dataclasses.is_dataclass(value):
        names = [f.name for f in dataclasses.fields(value)]
    elif hasattr(type(value), "model_fields"):
        names = list(type(value).model_fields)
    else:
        raise TypeError(f"no canonical form for {type(value).__name__}")
    # where a scenario was read from is data too, whether a field or an attribute
    return names + [n for n in ("source", "base_dir") if n not in names and hasattr(value, n)]


def _text(text: str, tmp: Path | None) -> str:
    if tmp is not None:
        text = text.replace(str(tmp), "<tmp>")
    return text.replace(str(ROOT), "<repo>")


# ----------------------------------------------------------------------------- the files
def _suite(path: Path) -> Any:
    from smarts.benchmark.suites import load_suite

    return load_suite(path)


def _metrics(path: Path) -> Any:
    from smarts.benchmark.metrics.params import load_params

    return load_params(path)


def _train(path: Path) -> Any:
    from train.config import load_config

    config = load_config(path.stem, path)
    return {
        "config": config,
        "interface": config.observation_interface(),
        "comms": config.comms_config(),
    }


def _scenario(path: Path) -> Any:
    from smarts.scenario import load_scenario

    return load_scenario(path)


def cases() -> dict[str, tuple[Any, Path]]:
    """Snapshot key -> (loader, file)."""
    out: dict[str, tuple[Any, Path]] = {}
    for path in sorted((ROOT / "configs" / "benchmark").glob("*.yaml")):
        out[f"configs/benchmark/{path.name}"] = (_metrics if path.stem == "metrics" else _suite, path)
    for path in sorted((ROOT / "configs" / "train").glob("*.yaml")):
        out[f"configs/train/{path.name}"] = (_train, path)
    for path in sorted((ROOT / "smarts" / "scenario" / "library").glob("*.yaml")):
        out[f"smarts/scenario/library/{path.name}"] = (_scenario, path)
    return out


def readme_scenario(tmp: Path) -> Any:
    """The README's example scenario, read from a file as a user would."""
    found = README_BLOCK.search((ROOT / "README.md").read_text(encoding="utf-8"))
    assert found, "README.md has no example scenario block (```yaml name: my_left_turn ...)"
    path = tmp / "my_left_turn.yaml"
    path.write_text(found.group(1), encoding="utf-8")
    return _scenario(path)


def dump(value: Any, tmp: Path | None = None) -> str:
    return json.dumps(canonical(value, tmp), indent=1, sort_keys=True)


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def current(tmp: Path) -> dict[str, str]:
    """Snapshot key -> full canonical dump, of every file as read now."""
    out = {key: dump(loader(path), tmp) for key, (loader, path) in cases().items()}
    out["README.md#scenario"] = dump(readme_scenario(tmp), tmp)
    return out


# ----------------------------------------------------------------------------- the test
def test_every_shipped_yaml_reads_into_the_recorded_values(tmp_path: Path) -> None:
    recorded = json.loads(SNAPSHOT.read_text(encoding="utf-8"))
    now = current(tmp_path)
    assert sorted(now) == sorted(recorded), "files added or removed: record the snapshot again"
    changed = [key for key, text in now.items() if digest(text) != recorded[key]]
    for key in changed:
        print(f"----- {key} (canonical dump as read now)\n{now[key]}")
    assert not changed, f"read into other values than recorded: {changed} (dumps printed above)"


if __name__ == "__main__":
    if sys.argv[1:] != ["--record"]:
        sys.exit(f"usage: python {Path(__file__).relative_to(ROOT)} --record")
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        texts = current(Path(folder))
    SNAPSHOT.write_text(json.dumps({k: digest(v) for k, v in sorted(texts.items())}, indent=1) + "\n")
    print(f"recorded {len(texts)} files in {SNAPSHOT.relative_to(ROOT)}")
