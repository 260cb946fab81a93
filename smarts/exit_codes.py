"""Exit codes shared by every command line (``smarts ...``, ``python -m train ...``,
``python -m smarts.viz``, ``python -m smarts.benchmark.metrics``): one code for one kind of
outcome, so a script can tell a mistake in what it passed from a failure on the way.

=====  ==================  ===================================================================
code   name                when
=====  ==================  ===================================================================
0      ``OK``              the command did what was asked
1      ``FAILED``          it started its work and could not finish it for a reason outside
                           its input: a disk that filled up or a folder that stopped taking
                           files mid-run, a tool (netconvert) that failed on a built-in map
2      ``BAD_INPUT``       something given to it is wrong, found before any work: an option
                           (argparse's own usage errors are 2 as well), a file, a field, a
                           scenario that does not validate, an agent, a checkpoint, an output
                           folder that cannot be written, a port that is in use
130    ``INTERRUPTED``     Ctrl-C (128 + SIGINT, as shells report it); what was saved is said
=====  ==================  ===================================================================

Every refusal is one line on stderr, ``error: <file, field, flag or agent>: <what is wrong>``,
without a traceback.
"""

from __future__ import annotations

OK = 0
FAILED = 1
BAD_INPUT = 2
INTERRUPTED = 130
