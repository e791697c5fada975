"""The open benchmark: every controller on a fixed suite of scenarios, over switch-on phases and
noise seeds, ranked like for like with intervals.

- :mod:`.suite`: the suite file (scenarios, controllers, ``[metrics]``, default phases and seeds);
- :mod:`.plan`: the uncontrolled reference runs (stick-slip period, stick-slip at switch-on) and
  the runs (scenario x controller x phase x seed, each seeded from those three);
- :mod:`.execute`: running them resumably, locally or on Dask;
- :mod:`.stats`: medians, bootstrap intervals, ranks with ties, the tables per actuator class;
- :mod:`.result`: :func:`run_benchmark` -> :class:`BenchmarkResult`;
- :mod:`.render`, :mod:`.figures`, :mod:`.write`: the report, the figures, the output set.
"""

from mitigate.benchmark.execute import RunStore, execute, run_task
from mitigate.benchmark.plan import Reference, RunTask, make_tasks, reference_run, run_seed
from mitigate.benchmark.render import render_ranking, verdict
from mitigate.benchmark.result import BenchmarkResult, references, run_benchmark
from mitigate.benchmark.stats import Entry
from mitigate.benchmark.suite import Suite, load_suite
from mitigate.benchmark.write import BENCHMARK_FILES, output_paths, write_benchmark

__all__ = ["Suite", "load_suite", "Reference", "RunTask", "make_tasks", "reference_run", "run_seed", "RunStore",
           "execute", "run_task", "Entry", "BenchmarkResult", "run_benchmark", "references",
           "render_ranking", "verdict", "write_benchmark", "output_paths", "BENCHMARK_FILES"]
