"""The open benchmark: every controller on a fixed suite of scenarios, over switch-on phases and
noise seeds, ranked like for like with intervals.

- :mod:`.suite`: the suite file (scenarios, controllers, ``[metrics]``, default phases and seeds);
- :mod:`.plan`: the uncontrolled reference runs (stick-slip period, stick-slip at switch-on) and
  the runs (scenario x controller x phase x seed, each seeded from those three);
- :mod:`.execute`: running them resumably, locally or on Dask;
- :mod:`.stats`: medians, bootstrap intervals, ranks with ties, the tables per actuator class;
- :mod:`.score`: one number per run in the ranking's order (what tuning minimises);
- :mod:`.result`: :func:`run_benchmark` -> :class:`BenchmarkResult` (:func:`assemble` from records);
- :mod:`.render`, :mod:`.figures`, :mod:`.write`: the report, the figures, the output set;
- :mod:`.entry`: ``results.json`` as a submittable entry and its JSON Schema (``results.schema.json``);
- :mod:`.leaderboard`: every entry of a frozen suite ranked like for like (Markdown and HTML);
- :mod:`.freeze`: what a suite version ties together (``suite.lock.json``);
- :mod:`.generate`: the generalisation set, generated from a seed.
"""

from mitigate.benchmark.execute import RunStore, execute, run_task
from mitigate.benchmark.plan import Reference, RunTask, make_tasks, reference_run, run_seed
from mitigate.benchmark.render import render_ranking, verdict
from mitigate.benchmark.result import BenchmarkResult, assemble, references, run_benchmark
from mitigate.benchmark.stats import Entry
from mitigate.benchmark.suite import Suite, load_suite
from mitigate.benchmark.write import BENCHMARK_FILES, output_paths, write_benchmark

__all__ = ["Suite", "load_suite", "Reference", "RunTask", "make_tasks", "reference_run", "run_seed", "RunStore",
           "execute", "run_task", "Entry", "BenchmarkResult", "run_benchmark", "assemble", "references",
           "render_ranking", "verdict", "write_benchmark", "output_paths", "BENCHMARK_FILES"]
