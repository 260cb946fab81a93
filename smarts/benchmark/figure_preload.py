"""What a benchmark report's figure helpers import before drawing (pyplot on the Agg backend, the
maps, the replay renderer), as a module the benchmark command's fork server imports beside the
workers' modules: helpers forked from it then draw at once. Importing it does that work; nothing
else imports it."""

from smarts.benchmark.report import prepare_drawing

prepare_drawing()
