"""Parameter sweeps: maps of where stick-slip appears and how large it is (seed 002, Figs. 9.31-9.33).

A sweep runs one open-loop simulation of a scenario per point of a grid over some of
its numeric fields and reduces each run, after a settling time, to the stick-slip
metrics the registry declares for a sweep point (:func:`mitigate.metrics.columns` ``("sweep")``),
one :class:`mitigate.record.RunRecord` per point.  Axes are written ``name=start:stop:count``
(``count`` points from ``start`` to ``stop`` inclusive, linear), where ``name`` is

- a model input (``n1``, ``omega_ref``, ``axial_force``, ``omega_drive``, ...): the
  scenario's profile for it is replaced by a constant [SI units];
- a plant parameter (``k1``, ``d1``, ``c``, ``K``, ...): the plant value is replaced;
- ``<param>_scale`` (e.g. ``K_scale``): the scenario's plant value is multiplied;
- ``mismatch.<param>``: the mismatch factor on the nominal value is replaced.

With a controller (``--controller NAME``, rig3 only) each point is instead one closed-loop run
of :func:`mitigate.closedloop.run_closed_loop` (estimator and controller keep the NOMINAL
model: a swept plant parameter is a plant/model mismatch for them).

Every point is run from rest and/or from steady sliding at its input
(``start = "rest" | "sliding" | "both"``); where the two differ, stick-slip exists
next to a stable steady sliding (bistability: it is triggered by disturbances).

Speed: the plant is the exact stick/slip step :func:`models.plant.hybrid_step_function`,
compiled once to C (gcc, on-disk cache keyed by the source hash; falls back to the
CasADi VM without a compiler), accumulated over blocks of time steps
(``mapaccum``) and mapped over the points of a chunk (``map``).  Chunks run in
worker processes, or on a Dask cluster (``scheduler``); CasADi's ``map(n, "thread", 2)``
gave no speed-up over the serial map here (benchmarks/results/sweep.md), processes do.  Results are written per
chunk by :class:`mitigate.sweep.store.SweepStore`, so an interrupted sweep resumes.  The
store's hash covers the axes, the options and the scenario file's content: editing the
scenario makes a rerun into the same folder a different sweep (refused without ``--force``).

The ``[sweep]`` table of a scenario sets defaults::

    [sweep]
    vary = ["n1=5:40:50", "omega_ref=1:8:50"]   # default axes (command-line --vary replaces them)
    start = "both"            # rest | sliding | both
    settle = 15.0             # [s] discarded before the metrics (default: half the duration)
    speed = "omega1"          # state whose speed gives severity, stuck fraction, frequency
    amplitude_of = "omega1"   # state whose half peak-to-peak is the amplitude (unit of that state)
    threshold = 0.05          # amplitude above which a point counts as a limit cycle (if also sustained:
                              # the late half of the window swings >= 80 % of the early half);
                              # default 1.6 % of the rig's nominal speed (of its steady twist, for a twist)
    perturbation = 0.01       # [rad/s] added to the contact speeds of a steady-sliding start
                              # (default 0.3 % of the nominal speed)
    stuck_threshold = 1e-6    # [rad/s] |speed| at or below which the body counts as stuck
                              # (default 3e-7 of the nominal speed: a numerical zero)
    chunk = 50                # points per chunk (unit of parallelism and of resuming)
    block = 200               # time steps per compiled call
    duration = 30.0           # [s] overrides scenario.duration for the sweep
    dt = 0.01                 # [s] overrides scenario.dt
    nsub = 10                 # substeps per dt (overrides plant.nsub)
    stability_points = 20     # linear stability of steady sliding on a sub-grid of at most this many
                              # values per axis (models.modal.sliding_stability; ~60 ms per point)
"""

from mitigate.sweep.chunks import ChunkTask, batched_step, run_chunk, sweep_metrics
from mitigate.sweep.execute import (SweepResult, assemble, closed_loop_controller, connect_scheduler, make_tasks,
                                    run_sweep, stability_indices, stability_subgrid)
from mitigate.sweep.plan import Axis, SweepOptions, SweepPlan, options_from_scenario, parse_axis, plan_sweep
from mitigate.sweep.store import SweepStore, definition_hash

__all__ = ["Axis", "parse_axis", "SweepOptions", "options_from_scenario", "SweepPlan", "plan_sweep", "sweep_metrics",
           "ChunkTask", "batched_step", "run_chunk", "make_tasks", "closed_loop_controller", "run_sweep", "assemble", "SweepResult",
           "connect_scheduler", "stability_indices", "stability_subgrid", "SweepStore", "definition_hash", "sweep"]


def sweep(scenario, axes=(), *, out, controller=None, force=False, workers=None, scheduler=None, progress=False,
          stability=True, maps=True, **options):
    """Run a sweep from Python: ``sweep("scenarios/sweep_rig3.toml", ["n1=5:40:20"], out="out/s")``.

    Parameters
    ----------
    scenario : a Scenario or a scenario file; axes : ``"name=start:stop:count"`` strings or
        :class:`Axis` (default: the scenario's ``sweep.vary``); out : the sweep folder (resumable);
    controller : a ``[[controllers]]`` name for closed-loop points; workers / scheduler : local
        processes or a Dask scheduler address; maps : also write the PNG maps;
        **options : :class:`SweepOptions` fields (start, duration, settle, chunk, ...)

    Returns
    -------
    SweepResult (``maps``, ``stability``, ``files``, ``status``)
    """
    import dataclasses

    from models.errors import ConfigError
    from mitigate.scenario import Scenario, load_scenario

    from models.files import check_output_dir, output_set

    check_output_dir(out)
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    opts = options_from_scenario(sc, **options)
    axes = list(axes) or list(sc.sweep.get("vary", []))
    if not all(isinstance(a, (str, Axis)) for a in axes):
        raise ConfigError(f"axes must be 'name=start:stop:count' strings or Axis objects, got {axes!r}")
    axes = [a if isinstance(a, Axis) else parse_axis(a, axis_units(sc)) for a in axes]
    plan = plan_sweep(sc, axes, opts)
    closed_loop_controller(plan, controller)          # refused before anything is written
    with output_set(out, [], force=True) as w:     # the lock: no second command into this folder meanwhile
        store = SweepStore(out, plan.definition(controller), force=force)
        res = run_sweep(plan, store, workers=workers, scheduler=scheduler, controller=controller, progress=progress,
                        stability=stability)
        if maps:
            from mitigate.sweep.maps import plot_maps
            model = sc.plant_model
            unit = model.state_units[model.states.index(opts.amplitude_of)]
            files = [w.final(f.name) for f in plot_maps(res, w.dir, title=f"{sc.name} ({opts.amplitude_of} amplitude)",
                                                        amp_unit=unit, threshold=opts.threshold, units=axis_units(sc))]
            res = dataclasses.replace(res, files={"results": store.root / "results.csv",
                                                  **{f.stem: f for f in files}})
    return res


def axis_units(sc) -> dict:
    """SI unit of every name an axis may have (inputs and parameters of the scenario's plant)."""
    m = sc.plant_model
    units = dict(zip(m.inputs, m.input_units))
    units.update({n: sc.plant_params.spec(n).unit for n in sc.plant_params.names()})
    return units
