"""``mitigate tune``: tune a controller's declared tunables on a scenario with a fixed budget."""

from __future__ import annotations


from mitigate.cliutil import add_command, add_common, emit_json, format_table
from models.errors import ConfigError

EPILOG = """\
Each trial runs the controller at --phases switch-on instants (halfway between the benchmark's
--grid phases over the scenario's measured stick-slip period) and --seeds tuning noise seeds, and
scores the mean of the score that follows the benchmark's ranking order (the job done, what the rig
sees, the time to suppress, the hardware loads, the effort: mitigate.benchmark.score). Optuna's
seeded TPE sampler proposes the values (the first trial is the controller's own options; a fifth of
the budget random start-up trials), a median pruner stops poor trials early. The study is kept in DIR/<scenario>__<controller>.journal: run the same command again
to continue it, or with a larger --budget to extend it (with --jobs 1 a continued study proposes
what an uninterrupted one would: the same values on any machine); --jobs processes share it, and
then the order of the trials depends on timing. The tuned values
are then compared with the defaults on --held-out-seeds seeds that neither the tuning nor the
benchmark uses, at the benchmark's phases. Written to DIR: the journal and tune_<scenario>__<controller>.json.
With --validate V the choice is made on V validation phases (quarter points of the grid, on their own
seeds) among the 3 best trials and the shipped options: tuning on 2 runs over-fits (a law at the edge
of the speed band can win on tie-breaks); a tie keeps the shipped options.

The tunables and their ranges are declared by each controller class (multiples of a natural unit
on the rig where the option has one: SoftSpeed's Kp in multiples of Z, f_t of the rig's lowest mode).

examples:
  mitigate tune scenarios/benchmark/established.toml --controller softspeed --budget 30 --out out/tune
  mitigate tune scenarios/stick_slip_30rpm.toml --controller NMPC --budget 40 --jobs 2 --out out/tune
  mitigate tune scenarios/benchmark/drillstring.toml --controller "D=doskil,gain_factor=3" --budget 20 --json
  mitigate tune scenarios/benchmark/established.toml --controller softspeed --budget 30 --validate 4 --out out/tune
"""


def register(sub) -> None:
    p = add_command(sub, "tune", help="tune a controller's declared tunables on a scenario (Optuna)",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("scenario", metavar="SCENARIO.toml", help="scenario file")
    p.add_argument("--controller", required=True, metavar="NAME",
                   help="a [[controllers]] name of the scenario, a kind (softspeed), or NAME=KIND[,opt=val,...]")
    p.add_argument("--budget", type=int, required=True, metavar="N", help="trials")
    p.add_argument("--phases", type=int, default=2, metavar="K", help="switch-on phases per trial (default 2)")
    p.add_argument("--seeds", type=int, default=1, metavar="S", help="tuning seeds per phase (default 1)")
    p.add_argument("--grid", type=int, default=6, metavar="K",
                   help="the benchmark's switch-on phases the tuning's lie between (default 6, the suite's)")
    p.add_argument("--held-out-seeds", type=int, default=2, metavar="H",
                   help="held-out seeds per phase for the report (default 2; 0: none)")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="processes sharing the study (default 1: reproducible; more: faster, but the trials' order, and so the "
                   "tuned values, depend on timing)")
    p.add_argument("--seed", type=int, default=0, help="the sampler's seed (default 0)")
    p.add_argument("--validate", type=int, default=0, metavar="V",
                   help="choose on V validation phases among the 3 best trials and the shipped options (default 0: "
                        "the best tuning score)")
    add_common(p, default_out="out/tune")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from mitigate.commands.benchmark import parse_controller
    from mitigate.scenario import load_scenario
    from mitigate.tune import tune
    from models.files import atomic_write_text

    for flag in ("budget", "phases", "seeds", "jobs", "grid"):
        if getattr(args, flag) < 1:
            raise ConfigError(f"--{flag} must be an integer >= 1, got {getattr(args, flag)}")
    if args.held_out_seeds < 0:
        raise ConfigError(f"--held-out-seeds must be an integer >= 0, got {args.held_out_seeds}")
    from mitigate.tune import validation_phases
    validation_phases(args.validate, args.grid, "--validate")
    sc = load_scenario(args.scenario)
    ctrl = parse_controller(args.controller) if "=" in args.controller else args.controller
    res = tune(sc, ctrl, budget=args.budget, phases=args.phases, seeds=args.seeds,
               held_out_seeds=args.held_out_seeds, out=args.out, n_jobs=args.jobs, seed=args.seed, force=args.force,
               progress=not args.json, grid=args.grid, validate=args.validate)
    from mitigate.benchmark.plan import slug
    path = Path(args.out) / f"tune_{slug(res.scenario)}__{slug(res.controller)}.json"
    atomic_write_text(path, json.dumps(res.as_dict(), indent=2) + "\n", overwrite=True)
    if args.json:
        emit_json(res.as_dict() | {"file": str(path)})
        return 0
    rows = [[n, res.best_params[n], res.tunables[n]["unit"], res.best_params[n] * res.tunables[n]["unit"],
             f"[{res.tunables[n]['low']:g}, {res.tunables[n]['high']:g}]"] for n in res.tunables]
    print(format_table(["tunable", "multiple", "unit on this rig", "value", "range (multiples)"], rows))
    print(f"\n{res.n_trials} trials ({res.n_complete} complete, {res.n_pruned} pruned); tuning score {res.best_value:.4g} "
          f"(the controller's own options: {res.default_value:.4g}); {res.elapsed:.0f} s")
    from mitigate.metrics import ranked
    for label, h in res.held_out.items():
        first = ranked()[0].name
        m = h[first]
        print(f"held-out, {label}: score {h['score']:.4g}; {first} {m['median']:.3g} [{m['ci_low']:.3g}, "
              f"{m['ci_high']:.3g}] over the runs that did the job; {h['n_runs']} runs ({h['failed']} failed, "
              f"{h['violations']} outside the bands or stalled)")
    if res.validation:
        rows = [[c["trial"], f"{c['tuning']:.4g}", f"{c['validation']:.4g}", "chosen" if c["trial"] == res.validation["chosen"]
                 else ""] for c in res.validation["candidates"]]
        print(f"\nvalidation at phases {', '.join(f'{f:.3g}' for f in res.validation['phases'])} of the period "
              "(trial 0: the shipped options):")
        print(format_table(["trial", "tuning score", "validation score", ""], rows))
    print(f"study: {res.study}; result: {path}")
    return 0
