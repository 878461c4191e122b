"""The ``raim`` command line: list and run scenarios (and more subcommands as they land).

Every subcommand is a pair of functions, ``_add_<name>(subparsers)`` and ``_cmd_<name>``;
``main`` wires them. Errors in user input exit with status 2 and one clear message.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from . import __version__

#: Error models whose sigmas come from elsewhere than sigma_m (the summary's header
#: names the model instead of sigma_m).
SIGMA_FREE_MODELS = frozenset({"rtklib", "broadcast", "araim"})


def _add_list(sub):
    p = sub.add_parser("list", help="list the built-in scenarios and algorithms")
    p.set_defaults(func=_cmd_list)


def _cmd_list(args) -> int:
    from . import algorithms
    from .scenario import list_scenarios, report_names, scenario_report

    print("Scenarios (raim run NAME; raim show NAME for a report):")
    for name, desc in list_scenarios().items():
        mark = " [report]" if scenario_report(name) else ""
        print(f"  {name:<18} {desc}{mark}")
    print(f"\nReports on real data (raim show NAME): {', '.join(report_names())}")
    print("\nAlgorithms (--algorithm A; raim keys A for their options):")
    for name in algorithms.names():
        spec = algorithms.get(name)
        opts = ", ".join(f"{k.name}={_fmt_value(k.default)}" for k in spec.options)
        print(f"  {name:<18} {spec.label}" + (f"  [options: {opts}]" if opts else ""))
    for mod, why in algorithms.failed().items():
        print(f"  (module {mod} failed to load: {why})")
    return 0


def _fmt_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, tuple):
        return "[" + ", ".join(_fmt_value(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def _add_keys(sub):
    p = sub.add_parser("keys", help="list the scenario keys and algorithm options",
                       description="Every key a scenario file, --set or the dashboard takes: "
                       "type, default, unit, allowed values and help.")
    p.add_argument("which", nargs="?", default=None, metavar="ALGORITHM|scenario",
                   help="only the options of this algorithm, or 'scenario' for the "
                        "scenario keys (default: all)")
    p.set_defaults(func=_cmd_keys)


def _cmd_keys(args) -> int:
    from . import algorithms
    from .scenario import scenario_keys

    groups = []
    if args.which in (None, "scenario"):
        groups.append(("scenario keys", list(scenario_keys().values())))
    if args.which != "scenario":
        names = algorithms.names() if args.which is None else [algorithms.get(args.which).name]
        groups += [(f"options of {n}", list(algorithms.get(n).options)) for n in names]
    for title, keys in groups:
        print(f"{title}:")
        for k in keys:
            unit = f" [{k.unit}]" if k.unit else ""
            print(f"  {k.name}{unit} = {_fmt_value(k.default)}  ({k.allowed}): {k.help}")
    return 0


def _add_show(sub):
    p = sub.add_parser("show", help="print a built-in scenario's report and file",
                       description="Print a built-in scenario's report (results against the "
                       "paper), when it has one, and its TOML file.")
    p.add_argument("scenario", help="built-in scenario name (see 'raim list')")
    p.set_defaults(func=_cmd_show)


def _cmd_show(args) -> int:
    from .scenario import _scenario_text, report_names, scenario_report

    if args.scenario in report_names():  # a report with no scenario file
        print(scenario_report(args.scenario).rstrip())
        return 0
    text, where = _scenario_text(args.scenario)
    report = scenario_report(args.scenario) if where.startswith("scenario ") else None
    print(report.rstrip() if report else f"# {where}\n\n(no report)")
    print(f"\n---\n{where}:\n\n{text.rstrip()}")
    return 0


RUN_EPILOG = """\
examples:
  raim run seed000-step --set sigma_m=3
  raim run seed000-ramp --out ramp.csv
  raim run default --fault G10,step,80,100,200 --fault G05,ramp,1.5,300
  raim run my_scenario.toml --algorithm parity --seed 7 --out result.json
  raim run --obs STATION.rnx --nav BRDC.rnx --fault G05,ramp,2,600   (a real recording)
  raim run --obs STATION.crx.gz --nav STATION_GN.rnx --nav STATION_EN.rnx.gz
  raim run --android gnss_log.txt --nav BRDC.rnx --set truth_ecef_m='[X, Y, Z]'

A recording (--obs with one or more --nav) runs every system the observation file has of
GPS, Galileo, GLONASS and BeiDou (--set systems='["GPS","GAL"]' chooses), one receiver
clock per system; the navigation files are merged (e.g. an IGS station's per-system _GN,
_EN, _CN and _RN files). Files may be compressed: .gz, .Z, .zip, Hatanaka .crx / .yyd.
A phone's Android GnssLogger raw log (--android instead of --obs) runs the same way, with
the measured error model; it has no header position: give truth_ecef_m.

--set takes any scenario key or option of the chosen algorithm ('raim keys' lists them,
with units and allowed values); values are TOML literals:
  --set sigma_m=3 --set systems='["GPS","BDS"]' --set baro=true
--fault replaces the scenario's faults (repeat it for several faults):
  SAT,step,BIAS_M,T0_S[,T1_S]    a bias of BIAS_M metres from T0_S until T1_S
  SAT,ramp,RATE_MPS,T0_S[,T1_S]  a bias growing at RATE_MPS metres per second from T0_S
SAT is a satellite (G10) or a system key of the scenario (GPS, BDS, GAL, GLO): a
constellation fault, e.g. GAL,step,20,300, biasing each of its satellites by the bias
times sin(elevation), as if its orbits were off by the bias along the receiver's
vertical (the same bias on all of them would be absorbed by that system's receiver clock).
"""


def _add_run(sub):
    p = sub.add_parser("run", help="run a scenario and print its summary",
                       description="Run one scenario through an algorithm, write the "
                       "per-epoch table and print a short summary.",
                       epilog=RUN_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_scenario_args(p)
    p.add_argument("--algorithm", "-a", help="algorithm to use (see 'raim list')")
    p.add_argument("--out", type=Path, help="write the table to PATH.csv or PATH.json")
    p.add_argument("--quiet", "-q", action="store_true", help="print only the summary JSON")
    p.set_defaults(func=_cmd_run)


def _add_scenario_args(p):
    """The arguments that choose and modify a scenario (shared by run and compare)."""
    p.add_argument("scenario", nargs="?",
                   help="built-in scenario name (see 'raim list') or a .toml file; optional "
                        "with --obs or --android")
    _add_recording_args(p)
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key or algorithm option (repeatable)")
    p.add_argument("--error-model", metavar="NAME", choices=_SchemaChoices("error_model"),
                   help="the pseudorange error model, one of %(choices)s (--set "
                        "error_model=NAME; 'raim keys scenario' says what each is)")
    p.add_argument("--fault", dest="faults", action="append", default=[], metavar="SPEC",
                   help="inject a fault, replacing the scenario's (repeatable; see below)")
    p.add_argument("--seed", type=int, help="random seed (same seed, same result)")


class _SchemaChoices:
    """The choices of a scenario key (:data:`raimcore.scenario.SCENARIO_KEYS`), looked up
    when argparse first needs them (a bad value, ``--help``): building the parser stays
    free of the scenario module's imports, and the choices are the schema's."""

    def __init__(self, key: str):
        self.key = key

    def _choices(self) -> tuple[str, ...]:
        from .scenario import SCENARIO_KEYS

        return tuple(SCENARIO_KEYS[self.key].choices)

    def __iter__(self):
        return iter(self._choices())

    def __contains__(self, value) -> bool:
        return value in self._choices()


def _add_recording_args(p):
    p.add_argument("--obs", help="RINEX 2.11/3.0x observation file: run on this recording "
                   "(plain, .gz, .Z, .zip or Hatanaka .crx/.yyd)")
    p.add_argument("--android", metavar="LOG",
                   help="Android GnssLogger raw log (format 1.4 or later, Raw records): "
                        "run on this phone recording instead of --obs")
    p.add_argument("--nav", action="append", metavar="NAV",
                   help="RINEX 2/3/4 navigation file for --obs or --android (GPS, Galileo, "
                        "GLONASS, BeiDou); repeatable: several files are merged")


def _recording_scenario(args, over: dict):
    """The scenario of ``--obs/--nav`` or ``--android/--nav`` (with a scenario file's keys
    when one is given), or None without them. ``args.nav`` is the list of ``--nav``
    files."""
    android = getattr(args, "android", None)
    if args.obs and android:
        raise ValueError("--obs and --android exclude each other: --obs takes a RINEX "
                         "observation file, --android a phone's GnssLogger log")
    obs, opt = (android, "--android") if android else (args.obs, "--obs")
    if not obs and not args.nav:
        if not args.scenario:
            raise ValueError("give a scenario (see 'raim list'), --obs FILE --nav FILE or "
                             "--android LOG --nav FILE")
        return None
    if not obs:
        raise ValueError("--nav needs --obs (a RINEX observation file) or --android (a "
                         "GnssLogger log)")
    if not args.nav:
        raise ValueError(f"{opt} and --nav go together (observation and navigation file)")
    from .scenario import load_scenario, recording_scenario

    rec = {"source": "android" if android else "rinex", "obs": obs, "nav": args.nav}
    if args.scenario:
        return load_scenario(args.scenario, **{**rec, **over})
    return recording_scenario(obs, args.nav, **{"source": rec["source"], **over})


def _overrides(args) -> dict:
    from .measure.faults import parse_fault
    from .scenario import parse_value

    over = {}
    for item in args.sets:
        if "=" not in item:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        key, val = item.split("=", 1)
        over[key.strip()] = parse_value(val.strip())
    if args.faults:
        over["faults"] = [parse_fault(f) for f in args.faults]
    if args.error_model:
        over["error_model"] = args.error_model
    if args.algorithm:
        over["algorithm"] = args.algorithm
    if args.seed is not None:
        over["seed"] = args.seed
    return over


def _check_out_file(path: Path | None) -> None:
    """Reject an ``--out`` path before the run, not after it: a .csv or .json file in a
    folder that exists."""
    if path is None:
        return
    if path.suffix.lower() not in (".csv", ".json"):
        raise ValueError(f"--out must end in .csv or .json, got {str(path)!r}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"--out: folder {str(folder)!r} does not exist (create it first)")
    if path.is_dir():
        raise ValueError(f"--out: {str(path)!r} is a folder; give a file name")


def _cmd_run(args) -> int:
    from .pipeline import run_scenario
    from .scenario import load_scenario

    _check_out_file(args.out)
    over = _overrides(args)
    scenario = _recording_scenario(args, over) or load_scenario(args.scenario, **over)
    result = run_scenario(scenario)
    if args.out is not None:
        if args.out.suffix.lower() == ".csv":
            result.table.to_csv(args.out)
        else:
            result.table.to_json(args.out)
    if args.quiet:
        print(json.dumps(result.summary.to_dict(), allow_nan=False))
    else:
        for note in result.summary.notes:
            print(f"note: {note}")
        print(format_summary(result))
        if args.out is not None:
            print(f"table written to {args.out}")
    return 0


def format_summary(result) -> str:
    """A short human-readable summary of a :class:`~raimcore.pipeline.ScenarioResult`:
    every rate with its counts and 95% interval, the epochs that enter no rate named."""
    s, sm = result.scenario, result.summary
    faults = ", ".join(
        f"{f.sat} {f.kind} " + (f"{f.bias_m:g} m" if f.kind == "step" else f"{f.rate_mps:g} m/s")
        + f" from t={f.t0_s:g} s" + (f" to {f.t1_s:g} s" if math.isfinite(f.t1_s) else "")
        for f in s.faults) or "none"
    m = result.measurements
    lines = [
        f"scenario {s.name}: algorithm {s.algorithm}, {sm.epochs} epochs, "
        f"{'+'.join(m.systems)} ({len(m.sat_names)} satellites), "
        + (f"error model {sm.error_model} " if sm.error_model in SIGMA_FREE_MODELS
           else f"sigma {s.sigma_m:g} m ")
        + f"({s.noise}"
        + (f", correlated over {s.noise_corr_s:g} s" if s.noise_corr_s > 0 else "")
        + f"), p_fa {result.p_fa:.3g}, faults: {faults}",
        f"  unavailable epochs (no position, in no rate): {sm.unavailable_epochs}"
        + (f"; detect-only epochs (one redundant measurement: no isolation): "
           f"{sm.detect_only_epochs}" if sm.detect_only_epochs else ""),
        f"  false-alarm rate on fault-free epochs: {sm.false_alarm}"
        + (f"; {sm.false_alarm_statement.rsplit(': ', 1)[1]} (error model {sm.error_model})"
           if sm.false_alarm_statement else ""),
    ]
    if sm.faulted_epochs:
        first = sm.first_alarm_t_s
        lines += [
            f"  fault from t = {sm.first_fault_t_s:g} s; first alarm: "
            + (f"t = {first:g} s" if first is not None else "never"),
            f"  detection rate over faulted epochs: {sm.detection} "
            f"(theory, ncx2: {_pct(sm.pd_theory_mean)})",
            f"  correct isolation rate over faulted epochs: {sm.correct_isolation}"
            + (" (every faulted epoch is detect-only or unavailable)"
               if sm.correct_isolation.n == 0 else ""),
            f"  mean HPE over faulted epochs: before isolation "
            f"{_m(sm.hpe_before_faulted_mean_m, 1)}, after {_m(sm.hpe_after_faulted_mean_m, 1)}",
        ]
    if sm.hpe_nominal_mean_m is not None:
        lines.append(f"  mean HPE on fault-free epochs: {sm.hpe_nominal_mean_m:.1f} m")
    if sm.fault_memory_epochs:
        lines.append(f"  epochs after a fault still in the algorithm's memory (not counted as "
                     f"fault-free): {sm.fault_memory_epochs}")
    if sm.rmse_before_m is not None:
        lines.append(f"  3-D position RMSE: before isolation {sm.rmse_before_m:.2f} m, "
                     f"after {_m(sm.rmse_after_m, 2)}"
                     + (f"; mean N_eff {sm.n_eff_mean:.1f}" if sm.n_eff_mean is not None
                        else ""))
    if sm.hpl_mean_m is not None:
        lines.append(f"  mean HPL {sm.hpl_mean_m:.1f} m, mean VPL {_m(sm.vpl_mean_m, 1)}"
                     + (f"; available (HPL <= HAL {s.hal_m:g} m and VPL <= VAL {s.val_m:g} m): "
                        f"{sm.pl_availability}" if sm.pl_availability is not None
                        and "emt_m" not in result.table.names else ""))
    import numpy as np

    from .scoring import Rate

    names = result.table.names
    if "emt_m" in names and "sigma_acc_m" in names:  # ARAIM: EMT, accuracy, LPV-200
        emt, acc = result.table["emt_m"], result.table["sigma_acc_m"]
        ok = np.isfinite(emt) & np.isfinite(acc)
        line = (f"  EMT median {np.median(emt[ok]):.1f} m, sigma_acc median "
                f"{np.median(acc[ok]):.2f} m" if ok.any() else "  EMT, sigma_acc: none")
        if "available" in names:
            av = np.asarray(result.table["available"], dtype=bool)
            line += (f"; available by every LPV-200 criterion (VPL, HPL, EMT, sigma_acc): "
                     f"{Rate(int(av.sum()), int(av.size))}")
        lines.append(line)
    if sm.baro_vpl_lower_share is not None:
        lines.append(f"  baro lowers VPL at {_pct(sm.baro_vpl_lower_share)} of epochs "
                     f"(not higher at {_pct(sm.baro_vpl_not_higher_share)}), "
                     f"lowers HPL at {_pct(sm.baro_hpl_lower_share)}")
    return "\n".join(lines)


def _m(x, digits: int) -> str:
    return "n/a" if x is None else f"{x:.{digits}f} m"


def _load_plugins(sub) -> None:
    """Subcommands that other packages register (entry-point group ``raim.commands``: a
    function ``add(subparsers)``). The dashboard comes this way from the ``app`` package, so
    ``raimcore`` never imports it; without it, ``raim dashboard`` says how to install it."""
    from importlib.metadata import entry_points

    have = set()
    for ep in entry_points(group="raim.commands"):
        try:
            ep.load()(sub)
            have.add(ep.name)
        except ImportError:  # the plugin's package is absent: fall back below
            continue
    if "dashboard" not in have:
        p = sub.add_parser("dashboard", help="start the web dashboard (not installed)",
                           description="The dashboard is not installed.")
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=_cmd_no_dashboard)


def _cmd_no_dashboard(args) -> int:
    raise ValueError("the dashboard is not installed: pip install 'raim-studio[app]' "
                     "(it needs the app package, viser and plotly)")


COMPARE_EPILOG = """\
examples:
  raim compare seed002 --algorithms pf-llr,ekf      # the paper's PF against the EKF
  raim compare seed004-multi --algorithms gf,rs,qv,parity --set max_exclusions=3
  raim compare default --fault G10,step,60,100 --seeds 10
  raim compare --obs STATION.rnx --nav BRDC.rnx --fault G05,ramp,2,600
  raim compare --android gnss_log.txt --nav BRDC.rnx --error-model elevation

--fault and --set are as in 'raim run' (see 'raim run --help').

Every algorithm sees the same measurements (one noise draw a seed, the same faults).
With --seeds N the rates and errors are averaged over seeds seed..seed+N-1 (first alarm:
median). Options set with --set reach every algorithm that has them.
"""


def _add_compare(sub):
    p = sub.add_parser("compare", help="run several algorithms on the same measurements",
                       description="Run several algorithms on one scenario (the same noise "
                       "draw and faults) and print one line of headline numbers each.",
                       epilog=COMPARE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_scenario_args(p)
    p.add_argument("--algorithms", metavar="A,B,...",
                   help="comma-separated algorithm names (default: all registered)")
    p.add_argument("--seeds", type=int, default=1,
                   help="number of consecutive seeds to average over (default %(default)s)")
    p.add_argument("--out", type=Path, help="write the comparison to PATH.csv or PATH.json")
    p.set_defaults(func=_cmd_compare, algorithm=None)


#: (summary key, column title, format) of the comparison table.
COMPARE_COLUMNS = (
    ("false_alarm_rate", "false al.", "pct"),
    ("first_alarm_t_s", "1st alarm", "s"),
    ("detection_rate", "detected", "pct"),
    ("correct_isolation_rate", "isolated", "pct"),
    ("hpe_after_faulted_mean_m", "HPE flt m", "m"),
    ("rmse_before_m", "RMSE bef", "m"),
    ("rmse_after_m", "RMSE aft", "m"),
    ("unavailable_epochs", "unavail", "n"),
)


def _cmd_compare(args) -> int:
    from .pipeline import compare_algorithms
    from .scenario import SCENARIO_KEYS, load_scenario

    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    _check_out_file(args.out)
    names = None
    if args.algorithms:
        names = [n.strip() for n in args.algorithms.split(",") if n.strip()]
    over = _overrides(args)
    # Options go to the algorithms that take them (each must belong to at least one of the
    # compared algorithms); scenario keys to the scenario.
    opts = {k: v for k, v in over.items() if k not in SCENARIO_KEYS}
    over = {k: v for k, v in over.items() if k in SCENARIO_KEYS}
    scenario = _recording_scenario(args, over) or load_scenario(args.scenario, **over)
    seed0 = scenario.seed
    top = int(SCENARIO_KEYS["seed"].hi)
    if seed0 + args.seeds - 1 > top:
        raise ValueError(f"--seeds {args.seeds} from seed {seed0} goes past the largest "
                         f"seed {top}; use fewer seeds or a smaller --seed")
    per_seed = [compare_algorithms(scenario.replace(seed=seed0 + k), names, **opts)
                for k in range(args.seeds)]
    rows = []
    for j, res in enumerate(per_seed[0]):
        row = {"algorithm": res.scenario.algorithm}
        for key, _, _ in COMPARE_COLUMNS:
            vals = [r[j].summary.get(key) for r in per_seed]
            vals = [float(v) for v in vals if v is not None and not
                    (isinstance(v, float) and math.isnan(v))]
            agg = (sorted(vals)[len(vals) // 2] if key == "first_alarm_t_s"
                   else sum(vals) / len(vals)) if vals else None
            row[key] = agg
        rows.append(row)
    for note in per_seed[0][0].summary.notes:
        print(f"note: {note}")
    print(f"scenario {scenario.name}: {per_seed[0][0].summary['epochs']} epochs, "
          f"seed {seed0}" + (f"..{seed0 + args.seeds - 1}" if args.seeds > 1 else ""))
    print(format_comparison(rows))
    if args.out is not None:
        _write_rows(rows, args.out)
        print(f"comparison written to {args.out}")
    return 0


def format_comparison(rows: list[dict]) -> str:
    """The comparison rows of :func:`_cmd_compare` as an aligned text table."""
    width = max(9, *(len(r["algorithm"]) for r in rows))
    head = f"{'algorithm':<{width}}" + "".join(f" {t:>10}" for _, t, _ in COMPARE_COLUMNS)
    lines = [head]
    for r in rows:
        cells = []
        for key, _, kind in COMPARE_COLUMNS:
            v = r[key]
            if v is None:
                cells.append("-")
            elif kind == "pct":
                cells.append(_pct(v))
            elif kind == "s":
                cells.append(f"{v:g} s")
            elif kind == "n":
                cells.append(f"{v:g}")
            else:
                cells.append(f"{v:.2f}")
        lines.append(f"{r['algorithm']:<{width}}" + "".join(f" {c:>10}" for c in cells))
    return "\n".join(lines)


def _write_rows(rows: list[dict], path: Path) -> None:
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(rows, indent=1, allow_nan=False))
        return
    import csv

    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


MONTECARLO_EPILOG = """\
examples:
  raim montecarlo seed004-table2 --runs 1000 --workers 2 --out mc/
  raim montecarlo seed004-table1 --bias-scale 1 --out mc/
  raim montecarlo seed004-table2 --dask local --workers 2
  raim montecarlo seed004-table2 --dask tcp://scheduler:8786

Each table is run at every --bias-scale (default: 1 = the paper's setting as written, and 2,
see README "Group evidence fusion"). With --out, finished cells are recorded in
DIR/ledger.jsonl: running the same command again resumes an interrupted study.
"""


def _add_montecarlo(sub):
    p = sub.add_parser("montecarlo", help="run a Monte Carlo study (seed 004 tables)",
                       description="Run a reference Monte Carlo study and print our table "
                       "beside the paper's.", epilog=MONTECARLO_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("study", choices=["seed004-table1", "seed004-table2"])
    p.add_argument("--runs", type=int, default=5000,
                   help="Monte Carlo runs a cell (default %(default)s)")
    p.add_argument("--workers", type=int, default=1,
                   help="processes (default %(default)s: in this process)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on a Dask cluster at ADDRESS, or 'local' for a LocalCluster "
                        "of --workers processes (needs raim-studio[dask])")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="write CSV, Markdown and a resume ledger to DIR")
    p.add_argument("--seed", type=int, default=4, help="root seed (default %(default)s)")
    p.add_argument("--bias-scale", type=float, action="append", dest="scales",
                   metavar="X", help="fault bias scale factor (repeatable; default 1 and 2)")
    p.add_argument("--bias-unit", choices=["full", "group"], default="full",
                   help="fault unit: P_bias of the full set (spec, default) or of one "
                        "group (our hypothesis for the paper's unit, see README)")
    p.add_argument("--gate", action="store_true",
                   help="count an isolation only when the full-set chi-square test also "
                        "detects (default: every run scored, as the paper)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: when stderr is a terminal)")
    p.set_defaults(func=_cmd_montecarlo)


def _cmd_montecarlo(args) -> int:
    from .studies.seed004 import run_table

    if args.runs < 1:
        raise ValueError(f"--runs must be >= 1, got {args.runs}")
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    for x in args.scales or ():
        if not (math.isfinite(x) and x > 0):
            raise ValueError(f"--bias-scale must be a finite number > 0, got {x:g}")
    _, text = run_table(args.study, runs=args.runs, seed=args.seed,
                        scales=tuple(args.scales or (1.0, 2.0)), bias_unit=args.bias_unit,
                        gate=args.gate, workers=args.workers,
                        dask=args.dask, out_dir=args.out, progress=args.progress)
    print(text)
    if args.out is not None:
        print(f"results written to {args.out}/")
    return 0


def _pct(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f}%"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``raim run: error: ... (raim run --help)``."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="raim", description="RAIM Studio: GNSS integrity monitoring (RAIM) scenarios, "
        "algorithms and studies.")
    parser.add_argument("--version", action="version", version=f"raim {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for add in (_add_list, _add_keys, _add_show, _add_run, _add_compare, _add_montecarlo):
        add(sub)
    _load_plugins(sub)
    return parser


def main(argv=None) -> int:
    """Run the ``raim`` command; returns the exit status (2: bad input, 130: interrupted)."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("raim: interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:
        from .schema import is_input_error

        if not is_input_error(exc):
            return _bug(exc)
        print(f"raim: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `raim run ... | head`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:  # e.g. --out on a read-only disk: a message, not a traceback
        print(f"raim: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "),
              file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - a bug: show it, and ask for a report
        return _bug(exc)


def _one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (a value the user typed may hold a newline)."""
    return " ".join(str(exc).split("\n")).strip() or type(exc).__name__


def _bug(exc: BaseException) -> int:
    import traceback

    traceback.print_exception(exc)
    print(f"raim: internal error ({type(exc).__name__}); this is a bug in RAIM Studio, "
          "please report it with the command line and the traceback above", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
