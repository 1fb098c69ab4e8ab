"""``nni-simulate --case CASE --screen``: every contingency of a case, its critical clearing time per b and law.

Enumerates the contingencies (:mod:`nni_battery_controller.screening`: bus
faults and line-end faults cleared by tripping the line, ``--contingencies``,
``--contingency-file``), skips with the reason those whose trip islands the
network, runs the rest as tasks (:mod:`nni_battery_controller.screen_engine`:
here, on a LocalCluster, or on a Dask cluster), keeps every finished task's
rows (:mod:`nni_battery_controller.screen_store`: ``--out DIR``,
``--resume``), and prints the weakest contingencies per b and law; with
``--out`` it draws the heat map and the gain chart there, with ``--json`` it
writes everything. The options are parsed by
:mod:`nni_battery_controller.network_study` (one parser for ``--case``).
Pure python: no ROS import.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from nni_battery_controller.figures import screen_gain_chart, screen_heatmap
from nni_battery_controller.network_common import json_b, limit_words
from nni_battery_controller.screen_store import FORMAT, open_store
from nni_battery_controller.screening import (
    AVAILABLE_LAWS,
    FIRST_SWING_S,
    KINDS,
    CaseSpec,
    ScreenSettings,
    enumerate_contingencies,
    islanding_reason,
    network_of,
    parse_contingency,
)
from nni_battery_controller.study_common import software_version
from nni_battery_controller.options import LAW_GAIN_OPTIONS, NETWORK_NNI_GAINS
from nni_msgs_adapter.ros.cli_support import CliError, write_json
from nni_msgs_adapter.ros.defaults import controller_defaults

#: The options only --screen takes (argparse dests; their defaults are None or False on the parser).
SCREEN_ONLY = ("contingencies", "contingency_file", "laws", "workers", "scheduler", "out", "resume", "weakest",
               "chunk")
#: Options of the network study that a screen does not take, and why.
NOT_WITH_SCREEN = {
    "cct": "a screen finds every contingency's critical clearing time",
    "compare_laws": "a screen compares the laws of --laws contingency by contingency",
    "law": "a screen takes its laws with --laws",
    **{option.name: "a screen runs the speed laws with the controller node's default gains" for option in
       LAW_GAIN_OPTIONS},
    "delay_margin": "a screen searches clearing times, not delays",
    "plot": "a screen draws its heat map and gain chart into --out",
    "fault_bus": "a screen faults every bus (choose with --contingencies)",
    "trip_line": "a screen's line-end faults trip their line (choose with --contingencies)",
    **{name: "a screen runs without a communication link"
       for name in ("link_delay", "link_jitter", "link_loss", "link_seed")},
}
DEFAULT_WEAKEST = 10


def refuse_screen_options(args) -> None:
    """CliError for an option that does not go with (or without) ``--screen``."""
    if not args.screen:
        for name in SCREEN_ONLY:
            if getattr(args, name) not in (None, False):
                raise CliError(f"--{name.replace('_', '-')} applies to --screen only")
        return
    for name, why in NOT_WITH_SCREEN.items():
        if getattr(args, name) not in (None, False):
            raise CliError(f"--{name.replace('_', '-')} does not apply to --screen: {why}")
    if args.scenario != "bus_fault":
        raise CliError("--screen screens bus faults and line-end faults: it takes no --scenario")
    if len(args.reference) != 1:
        raise CliError("--screen takes one --reference (a second is another screen)")
    if args.scheduler is not None and args.workers is not None:
        raise CliError("--workers sizes the LocalCluster started here; the cluster at --scheduler has its own")
    if args.resume and args.out is None:
        raise CliError("--resume needs --out DIR (the folder of the screen to continue)")


def law_names(words) -> tuple:
    """The laws of ``--laws`` (space- or comma-separated), each one this build can screen; CliError otherwise."""
    names = [name for word in (words or ["nni"]) for name in word.split(",") if name]
    for name in names:
        if name not in AVAILABLE_LAWS:
            raise CliError(f"--laws {name}: not a law (laws: {', '.join(AVAILABLE_LAWS)})")
    if len(set(names)) != len(names):
        raise CliError(f"--laws names a law twice: {', '.join(names)}")
    return tuple(names)


def select_contingencies(net, words, file) -> list:
    """The contingencies of ``--contingencies`` (kinds and names, comma-separated) and ``--contingency-file``."""
    entries = [word for text in (words or []) for word in text.split(",") if word]
    if file is not None:
        try:
            lines = Path(file).read_text(encoding="utf-8").splitlines()
        except OSError as error:
            raise CliError(f"--contingency-file {file}: {error.strerror}") from None
        entries += [line.split("#", 1)[0].strip() for line in lines if line.split("#", 1)[0].strip()]
    if not entries:
        entries = list(KINDS)
    chosen, seen = [], set()
    for entry in entries:
        found = enumerate_contingencies(net, (entry,)) if entry in KINDS else [parse_contingency(net, entry)]
        for contingency in found:
            if contingency.name not in seen:
                seen.add(contingency.name)
                chosen.append(contingency)
    return chosen


def settings_of(args, laws) -> ScreenSettings:
    """The screen's settings from the command line."""
    defaults = controller_defaults()
    nni = {key: tuple(getattr(args, dest) or [defaults[key]]) for dest, _, key in NETWORK_NNI_GAINS}
    return ScreenSettings(
        limits_pu=tuple(float(b) for b in args.b), laws=laws, reference=args.reference[0], **nni,
        duration_s=args.duration,
        rate_hz=args.controller_rate, cct_max_s=args.cct_max,
        clearing_time_s=0.1 if args.clearing_time is None else args.clearing_time,
        fault_impedance_pu=(args.fault_r or 0.0, args.fault_x or 0.0))


def _cct_text(row) -> str:
    if row["cct_s"] is None:
        return "none"
    return f">= {row['cct_s']:.3f}" if row["at_search_limit"] else f"{row['cct_s']:.3f}"


def _verdict_text(row) -> str:
    return row["verdict"] + ("" if row["loss_at_s"] is None else f" at {row['loss_at_s']:.2f} s")


def cct_key(row) -> float:
    """Sort key of a row: its CCT, a contingency lost even at the shortest clearing time first."""
    return -1.0 if row["cct_s"] is None else row["cct_s"]


def weakest_tables(rows, settings: ScreenSettings, count: int) -> list[str]:
    """Per law and b, the ``count`` contingencies with the shortest CCT, as lines."""
    lines = []
    for law in settings.laws:
        for b in settings.limits_pu:
            mine = sorted((row for row in rows if row["law"] == law and row["b"] == b), key=cct_key)
            lines += [f"  {limit_words(b)}, law {law}: the {min(count, len(mine))} weakest of {len(mine)}",
                      f"    {'rank':>4} {'contingency':<22} {'CCT (s)':>9}  "
                      f"{'at ' + format(settings.clearing_time_s, 'g') + ' s':<26} weakest generator"]
            for rank, row in enumerate(mine[:count], start=1):
                lines.append(f"    {rank:>4} {row['contingency']:<22} {_cct_text(row):>9}  {_verdict_text(row):<26} "
                             f"{row['weakest_generator']} ({row['weakest_swing_deg']:.0f} deg)")
    return lines


def _skipped_lines(skipped) -> list[str]:
    """One line per skipped line (both ends share the reason)."""
    by_reason = {}
    for entry in skipped:
        by_reason.setdefault(entry["reason"], []).append(entry["contingency"])
    return [f"  {', '.join(names)}: {reason}" for reason, names in by_reason.items()]


def run_screen(args) -> int:
    """``nni-simulate --case CASE --screen ...`` (parsed and checked by network_study)."""
    started = time.perf_counter()
    laws = law_names(args.laws)
    spec = CaseSpec.of(args.case, args.machines, args.f0)
    net = network_of(spec)
    settings = settings_of(args, laws)
    contingencies = select_contingencies(net, args.contingencies, args.contingency_file)
    skipped = [{"contingency": c.name, "reason": reason} for c in contingencies
               if (reason := islanding_reason(net, c)) is not None]
    skipped_names = {entry["contingency"] for entry in skipped}
    screened = [c.name for c in contingencies if c.name not in skipped_names]
    manifest = {"format": FORMAT, "case": args.case, "case_digest": spec.digest(), "software_version": software_version(),
                "generators": list(net.names), "settings": settings.to_json(), "contingencies": screened,
                "skipped": skipped}
    store = open_store(args.out, manifest, args.resume)
    done = store.done()
    to_do = [(i, name) for i, name in enumerate(screened) if name not in done]
    chunk = args.chunk or 1
    tasks = [(to_do[k][0], tuple(name for _, name in to_do[k:k + chunk])) for k in range(0, len(to_do), chunk)]
    kinds = {kind: sum(1 for c in contingencies if c.kind == kind) for kind in KINDS}
    print(f"{args.case}: dynamic security screen of {len(contingencies)} contingencies ({kinds['bus']} bus faults, "
          f"{kinds['line']} line-end faults cleared by tripping the line), {len(skipped)} skipped; "
          f"b {' '.join(f'{b:g}' for b in settings.limits_pu)} pu, law {', '.join(laws)}, reference "
          f"{settings.reference}; {settings.duration_s:g} s runs, controller {settings.rate_hz:g} Hz; CCT by "
          f"bisection to {settings.resolution_s * 1e3:g} ms up to {settings.cct_max_s:g} s; verdict of a run cleared "
          f"at {settings.clearing_time_s:g} s (first-swing loss: within {FIRST_SWING_S:g} s of clearing)")
    if skipped:
        print(f"skipped, the trip islands the network ({len(skipped)}):")
        print("\n".join(_skipped_lines(skipped)))
    if done:
        print(f"resumed {args.out}: {len(done)} of {len(screened)} contingencies already there, "
              f"{len(to_do)} to compute")
    from nni_battery_controller.screen_engine import default_workers, run_tasks

    workers = default_workers() if args.workers is None else args.workers
    try:
        stats = run_tasks(spec, settings, tasks, store, workers, args.scheduler) if tasks else \
            {"engine": "none (nothing left to compute)", "workers": 0, "tasks": 0, "compute_s": 0.0, "wall_s": 0.0}
    except KeyboardInterrupt:
        kept = f"; {len(store.done())} of {len(screened)} contingencies are in {args.out} (--resume continues)" \
            if args.out is not None else "; nothing kept (no --out)"
        print(f"nni-simulate: interrupted{kept}", file=sys.stderr)
        raise
    rows = sorted(store.rows, key=lambda row: (screened.index(row["contingency"]), laws.index(row["law"]),
                                               settings.limits_pu.index(row["b"])))
    print(f"weakest contingencies (shortest critical clearing time first; 'none': lost even when cleared at "
          f"{settings.resolution_s * 1e3:g} ms):")
    print("\n".join(weakest_tables(rows, settings, args.weakest or DEFAULT_WEAKEST)))
    wrote = _figures(args, rows, screened, settings) if args.out is not None else []
    elapsed = time.perf_counter() - started
    share = _overhead_share(stats)
    print(f"({elapsed:.1f} s; {len(to_do)} contingencies computed by {stats['engine']}"
          + (f", {stats['workers']} workers" if stats["workers"] else "")
          + (f", task overhead {100 * share:.1f} % of the workers' time" if share is not None else "") + ")")
    if args.json:
        write_json(args.json, {**{key: manifest[key] for key in manifest if key != "format"},
                               "rows": [{**row, "b": json_b(row["b"])} for row in rows],
                               "engine": stats, "elapsed_s": elapsed})
        wrote.append(str(args.json))
    if wrote:
        print(f"wrote {', '.join(wrote)}")
    return 0


def _overhead_share(stats) -> float | None:
    """What the workers spent outside the tasks' computing (scheduling, transfers, idle at the end), of their time."""
    if not stats["workers"] or stats["wall_s"] <= 0:
        return None
    return max(0.0, 1.0 - stats["compute_s"] / (stats["workers"] * stats["wall_s"]))


def _figures(args, rows, screened, settings) -> list[str]:
    """The heat map and (with b = 0 screened) the gain chart in --out; what was written, or why not."""
    columns = [(law, b) for law in settings.laws for b in settings.limits_pu]
    what = f"law {', '.join(settings.laws)}, reference {settings.reference}, {settings.duration_s:g} s runs"
    heatmap = Path(args.out) / "heatmap.png"
    screen_heatmap(rows, screened, columns, f"{args.case}: critical clearing time per contingency and battery limit "
                   f"({what})", settings.cct_max_s, heatmap)
    wrote = [str(heatmap)]
    if 0.0 not in settings.limits_pu or len(settings.limits_pu) < 2:
        print("no CCT gain chart: --b needs 0 (no battery) and at least one battery to compare with it")
        return wrote
    gain = Path(args.out) / "cct_gain.png"
    screen_gain_chart(rows, screened, [(law, b) for law, b in columns if b != 0.0],
                      {law: (law, 0.0) for law in settings.laws},
                      f"{args.case}: critical clearing time gain with batteries per contingency ({what})", gain)
    return wrote + [str(gain)]
