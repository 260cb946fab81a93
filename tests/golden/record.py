"""Record the golden trajectories: ``python -m tests.golden.record`` (about a minute).

Steps every golden case (``tests.golden.cases``) with every seed on the per-env backend and writes
``tests/golden/golden.json``. Re-record only when a change is meant to alter trajectories, and say
in the commit which cases changed and why; ``tests/golden/test_golden.py`` holds every backend to
this file.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from tests.golden.cases import MAX_STEPS, SEEDS, all_cases
from tests.golden.run import run_single

GOLDEN = Path(__file__).with_name("golden.json")


def record(only: list[str] | None = None) -> dict:
    data = json.loads(GOLDEN.read_text()) if only and GOLDEN.exists() else {"max_steps": MAX_STEPS, "cases": {}}
    with tempfile.TemporaryDirectory() as work:
        for case in all_cases():
            if only and not any(case.name.startswith(o) for o in only):
                continue
            start = time.perf_counter()
            spec = case.load(Path(work))
            data["cases"][case.name] = {str(s): run_single(spec, s).to_json() for s in SEEDS}
            lengths = [len(e["steps"]) // 8 for e in data["cases"][case.name].values()]
            print(f"{case.name}: {lengths} steps, {time.perf_counter() - start:.1f} s", flush=True)
    return data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="re-record only the cases whose names start with these")
    args = parser.parse_args()
    data = record(args.only)
    GOLDEN.write_text(json.dumps(data, indent=0, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN} ({len(data['cases'])} cases)")


if __name__ == "__main__":
    main()
