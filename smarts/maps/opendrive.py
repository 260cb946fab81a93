"""OpenDRIVE (.xodr) support by conversion to a SUMO network with netconvert.

Converting keeps one compiled representation (the SUMO network) for both formats, and the same
``.net.xml`` can then drive SUMO traffic on an OpenDRIVE map.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from smarts.maps.errors import MapError


def netconvert_binary() -> str:
    """Path of netconvert: from PATH, else from the eclipse-sumo package."""
    found = shutil.which("netconvert")
    if found:
        return found
    try:
        import sumo  # the eclipse-sumo wheel ships the SUMO binaries

        candidate = os.path.join(sumo.SUMO_HOME, "bin", "netconvert")
    except ImportError:
        candidate = ""
    if candidate and os.path.exists(candidate):
        return candidate
    raise MapError("netconvert not found: install the 'eclipse-sumo' package or put SUMO on PATH")


def convert_opendrive(path: Path, out_dir: Path) -> Path:
    """Convert ``path`` (.xodr) into ``out_dir/<name>.net.xml`` and return that path.

    Node positions are kept as in the OpenDRIVE file (no offset normalisation) so map coordinates
    match the source; internal junction lanes are kept.
    """
    path = Path(path)
    if not path.is_file():
        raise MapError(f"{path}: OpenDRIVE file not found")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = path.name[: -len(".xodr")] if path.name.lower().endswith(".xodr") else path.stem
    output = out_dir / f"{name}.net.xml"
    partial = output.with_name(output.name + ".partial")
    command = [
        netconvert_binary(),
        "--opendrive-files",
        str(path),
        "--output-file",
        str(partial),
        "--offset.disable-normalization",
        "true",
    ]
    try:
        result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        raise MapError(f"{path}: netconvert did not finish converting within 600 s") from None
    if result.returncode != 0 or not partial.is_file():
        partial.unlink(missing_ok=True)
        detail = (result.stderr or result.stdout).strip()[-2000:]
        raise MapError(
            f"{path}: netconvert could not convert the OpenDRIVE file "
            f"(exit code {result.returncode}): {detail}"
        )
    partial.replace(output)
    return output
