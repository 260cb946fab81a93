"""A unit runner for the worker-pool tests: it reports where and in what environment it ran."""

from __future__ import annotations

import os

PROBE_VAR = "SMARTS_TEST_WORKER_PROBE"


def where_and_what(jobs, policy_resolver, report) -> None:
    for i in range(len(jobs)):
        report(i, {"cwd": os.getcwd(), "probe": os.environ.get(PROBE_VAR), "pid": os.getpid()})
