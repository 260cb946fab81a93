"""The benchmark's fork server does without torch: a worker running policies of code alone never
imports it, and one whose policy is a network imports it with one thread."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TINY = str(Path(__file__).with_name("tiny_suite.yaml"))

SCRIPT = """
import json, sys
from smarts.worker_processes import start_worker_server
start_worker_server(torch=False)  # as train benchmark starts it
from smarts.benchmark.jobs import plan_jobs
from smarts.benchmark.runner import run_jobs
from smarts.benchmark.suites import load_suite
from tests.benchmark.broken_agent import probe_resolver
jobs = plan_jobs(["test:code-probe", "test:net-probe"], load_suite(sys.argv[1]), 1, sys.argv[2], references=False,
                 policy_resolver=probe_resolver)
results = run_jobs(jobs, workers=2, progress=False, policy_resolver=probe_resolver)
print(json.dumps(sorted({r["failure"].split(": ", 1)[1] for r in results})))
"""


def test_workers_import_torch_only_for_a_network_and_then_on_one_thread(tmp_path):
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}  # no OMP_NUM_THREADS from the caller
    done = subprocess.run([sys.executable, "-c", SCRIPT, TINY, str(tmp_path / "out")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == ["torch imported: False", "torch threads: 1"]
