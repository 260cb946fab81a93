"""OpenDRIVE (.xodr) support by conversion to a SUMO network with netconvert.

Converting keeps one compiled representation (the SUMO network) for both formats, and the same
``.net.xml`` can then drive SUMO traffic on an OpenDRIVE map.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import warnings
from pathlib import Path

from smarts.maps.errors import MapError, MapWarning


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


IGNORED_ERRORS_NAME = "netconvert-ignored-errors.txt"
"""File written next to a converted network that netconvert could only build with
``--ignore-errors``: the errors it ignored, one a line."""
MAX_LISTED_ERRORS = 20


class ConversionError(MapError):
    """netconvert rejected the OpenDRIVE file, also with ``--ignore-errors`` (a property of the
    file and the netconvert version, so the loader caches it). ``detail`` is the message without
    the file name."""

    def __init__(self, path: Path, detail: str):
        super().__init__(f"{path}: {detail}")
        self.detail = detail


def netconvert_identity(binary: str | None = None) -> str:
    """A cheap fingerprint of the netconvert in use (path, size, modification time): a cached
    failed conversion is retried when netconvert changes."""
    binary = binary or netconvert_binary()
    real = os.path.realpath(binary)
    try:
        st = os.stat(real)
        return f"{real}:{st.st_size}:{st.st_mtime_ns}"
    except OSError:
        return real


def convert_opendrive(path: Path, out_dir: Path) -> Path:
    """Convert ``path`` (.xodr) into ``out_dir/<name>.net.xml`` and return that path.

    Node positions are kept as in the OpenDRIVE file (no offset normalisation) so map coordinates
    match the source; internal junction lanes are kept.

    netconvert is strict by default: one bad element (e.g. a lane link naming a road the file
    does not have) fails the whole file. Such a file is converted again with ``--ignore-errors``;
    when that succeeds, a warning lists what netconvert ignored and the list is written to
    ``out_dir/netconvert-ignored-errors.txt``. When both fail, :class:`ConversionError` carries
    netconvert's messages.
    """
    path = Path(path)
    if not path.is_file():
        raise MapError(f"{path}: OpenDRIVE file not found")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = path.name[: -len(".xodr")] if path.name.lower().endswith(".xodr") else path.stem
    output = out_dir / f"{name}.net.xml"
    partial = output.with_name(output.name + ".partial")
    strict = _run_netconvert(path, partial, ignore_errors=False)
    if strict.returncode == 0 and partial.is_file():
        partial.replace(output)
        return output
    partial.unlink(missing_ok=True)
    lenient = _run_netconvert(path, partial, ignore_errors=True)
    if lenient.returncode != 0 or not partial.is_file():
        partial.unlink(missing_ok=True)
        detail = (lenient.stderr or lenient.stdout or strict.stderr or strict.stdout).strip()
        raise ConversionError(
            path,
            f"netconvert could not convert the OpenDRIVE file (exit code {lenient.returncode}, "
            f"also with --ignore-errors): {detail[-2000:]}",
        )
    ignored = _error_lines(strict.stderr + "\n" + lenient.stderr)
    (out_dir / IGNORED_ERRORS_NAME).write_text("".join(f"{line}\n" for line in ignored))
    partial.replace(output)
    warn_ignored_errors(path, ignored)
    return output


def warn_ignored_errors(path: Path, ignored: list[str]) -> None:
    """Warn that the network of ``path`` was built by skipping what netconvert rejected."""
    listed = ignored[:MAX_LISTED_ERRORS]
    more = len(ignored) - len(listed)
    lines = "\n".join(f"  {line}" for line in listed) + (f"\n  ... and {more} more" if more else "")
    warnings.warn(
        f"{path}: netconvert rejected parts of this OpenDRIVE file and converted it with "
        f"--ignore-errors; what it ignored (missing from the road network):\n{lines or '  (no messages)'}",
        MapWarning,
        stacklevel=3,
    )


def _run_netconvert(path: Path, output: Path, ignore_errors: bool) -> subprocess.CompletedProcess:
    command = [
        netconvert_binary(),
        "--opendrive-files",
        str(path),
        "--output-file",
        str(output),
        "--offset.disable-normalization",
        "true",
    ]
    if ignore_errors:
        command += ["--ignore-errors", "true"]
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        output.unlink(missing_ok=True)
        raise MapError(f"{path}: netconvert did not finish converting within 600 s") from None


def _error_lines(text: str) -> list[str]:
    """netconvert's distinct error messages, in order."""
    seen: dict[str, None] = {}
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("Error:") and line != "Error: Quitting (on error).":
            seen.setdefault(line[len("Error:") :].strip(), None)
    return list(seen)
