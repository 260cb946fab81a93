"""One exit code for one kind of outcome across the command lines (``smarts.exit_codes``): a bad
scenario file is 2 whether it is validated or shown, a port in use is one plain line and 2, a
mid-run write failure is 1."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from smarts import exit_codes
from smarts.__main__ import main as smarts_main

BAD = "name: x\nmap: builtin:straight_2lane\nagents:\n  - mission: {start: {road: main, ofset: 3}, goal: {road: main, offset: 50}}\n"


def test_a_bad_scenario_file_is_the_same_code_for_validate_and_show(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(BAD)
    codes = {
        "validate": smarts_main(["scenario", "validate", str(bad)]),
        "show": smarts_main(["scenario", "show", str(bad)]),
        "show --build": smarts_main(["scenario", "show", str(bad), "--build"]),
        "unknown map": smarts_main(["map", "build", "moon_base"]),
        "unreadable recording": smarts_main(["replay", "info", str(bad), "--format", "waymo"]),
    }
    assert codes == dict.fromkeys(codes, exit_codes.BAD_INPUT), codes
    err = capsys.readouterr()
    assert "ofset" in err.out + err.err and "Traceback" not in err.err


def test_a_port_in_use_is_one_clear_line(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "smarts", "viz", str(tmp_path), "--port", str(port)],
                              capture_output=True, text=True, timeout=120, cwd=Path(__file__).parents[1])  # fmt: skip
    assert done.returncode == exit_codes.BAD_INPUT, done.stderr
    lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
    assert lines == [f"error: --port {port}: 127.0.0.1:{port} is already in use (another viewer or server?); give "
                     "another --port, or --port 0 for any free one"]  # fmt: skip


def test_the_codes_are_distinct():
    codes = [exit_codes.OK, exit_codes.FAILED, exit_codes.BAD_INPUT, exit_codes.INTERRUPTED]
    assert len(set(codes)) == 4 and exit_codes.BAD_INPUT == 2  # argparse's usage errors are 2 as well


def test_python_m_train_ends_without_teardown_but_after_its_exit_handlers(tmp_path):
    """``python -m train`` skips the interpreter's teardown (unloading torch alone is half a
    second): its exit status is the command's, what it printed is flushed (also into a pipe), and
    exit handlers still run (worker pools, TensorBoard writers)."""
    code = (
        "import atexit, sys\n"
        "from train.__main__ import exit_without_teardown\n"
        "atexit.register(lambda: sys.stdout.write('handler ran'))\n"
        "sys.stdout.write('printed, ')\n"
        "exit_without_teardown(3)\n"
        "sys.stdout.write('never')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          cwd=Path(__file__).parents[1])  # fmt: skip
    assert (done.returncode, done.stdout) == (3, "printed, handler ran"), done.stderr
    help_run = subprocess.run([sys.executable, "-m", "train", "benchmark", "--help"], capture_output=True, text=True,
                              timeout=60, cwd=Path(__file__).parents[1])  # fmt: skip
    assert help_run.returncode == 0 and "--episodes" in help_run.stdout
    script = tmp_path / "ends.py"
    script.write_text(f"import sys; sys.path.insert(0, {str(Path(__file__).parents[1])!r})\n{code}")
    profiled = subprocess.run([sys.executable, "-m", "cProfile", str(script)], capture_output=True, text=True,
                              timeout=60, cwd=Path(__file__).parents[1])  # fmt: skip
    assert "handler ran" in profiled.stdout and "function calls" in profiled.stdout  # the profiler still reports
