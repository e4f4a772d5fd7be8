"""The ``scenenav`` command: one subcommand per capability, each with its own --help.

Errors in what the user gave (files, keys, values) print one line ``error: ...`` and exit 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import sys
from pathlib import Path

from scenenav.app.arg_types import (
    add_flight_kind_arguments,
    ipv4_address,
    nonneg_int,
    port_number,
    positive_int,
)

DEFAULT_LIVE_PORT = 8765          # Foxglove's default WebSocket port (scenenav.app.live)
from scenenav.app.json_output import emit_json, run_json_aware
from scenenav.core.errors import UserError

log = logging.getLogger("scenenav")


def _run(args: argparse.Namespace) -> int:
    from scenenav.app.evaluation import format_summary, plain_summary
    from scenenav.app.launcher import run
    try:
        summary = run(args.scenario, args.out, tuple(args.set or ()), progress=not args.quiet,
                      live_port=args.live_port if args.live else None,
                      external=tuple(args.external or ()),
                      announce=lambda text: print(text, file=sys.stderr, flush=True))
    except KeyboardInterrupt:
        # the launcher wrote the summary of what was flown before it re-raised: say it
        try:
            stopped = json.loads((Path(args.out) / "summary.json").read_text())
        except (OSError, ValueError):
            stopped = None
        if stopped is not None:
            print(plain_summary(stopped, Path(args.out)))
            print(f"run folder: {args.out}")
        raise
    print(format_summary(summary))
    print()
    print(plain_summary(summary, Path(args.out)))
    print(f"run folder: {args.out}")
    return 0 if not (summary.get("failed_nodes") or summary.get("aborted")) else 1


def _summarize(args: argparse.Namespace) -> int:
    from scenenav.app.evaluation import format_summary, summarize_run
    summary = summarize_run(Path(args.run_dir))
    print(format_summary(summary))
    print(f"rebuilt: {Path(args.run_dir) / 'summary.json'}, {Path(args.run_dir) / 'trajectory.png'}")
    return 0


def _node(args: argparse.Namespace) -> int:
    from scenenav.app import nodes
    from scenenav.core.bus import BusConfig
    run_dir = Path(args.run_dir) if getattr(args, "run_dir", None) else None
    if args.kind == "sim":
        bus = BusConfig(args.namespace, args.hub_port, listen_hub=True, listen_host=args.listen_host)
        expect = tuple(x for x in (args.expect or "").split(",") if x)
        return nodes.run_sim(run_dir, bus, expect)
    bus = BusConfig(args.namespace, args.hub_port, host=args.hub_host, listen_host=args.listen_host)
    if args.kind == "recorder":
        return nodes.run_recorder(run_dir, bus)
    if args.kind == "perception":
        return nodes.run_perception(run_dir, bus, args.method, args.node_id, args.world,
                                    args.assistant_map, None if args.lockstep is None else args.lockstep == "on")
    if args.kind == "autopilot":
        return nodes.run_autopilot(run_dir, bus)
    if args.kind == "live":
        if run_dir is None:
            raise UserError("node live: --run-dir is required (the run's scenario.yaml names the world)")
        return nodes.run_live(run_dir, bus, args.live_port)
    if args.kind == "guidance":
        if run_dir is None:
            raise UserError("node guidance: --run-dir is required (the run's scenario.yaml names the goals)")
        return nodes.run_guidance(run_dir, bus)
    raise UserError(f"unknown node kind {args.kind!r}")


def _node_check(args: argparse.Namespace) -> int:
    from scenenav.app.node_check import CheckOptions, format_report, run_check
    command = list(args.command or ())
    opts = CheckOptions(role=args.role, command=tuple(command), node_id=args.node_id,
                        duration_s=args.duration_s, ack_timeout_s=args.ack_timeout_s,
                        scenario=args.scenario, overrides=tuple(args.set or ()), out=args.out)
    report = run_check(opts, say=lambda text: print(text, file=sys.stderr, flush=True))
    if args.json:
        emit_json(report)
    else:
        print(format_report(report), end="")
    return 0 if report["passed"] else 1


def _bench(args: argparse.Namespace) -> int:
    if args.what == "sim":
        from scenenav.app.bench.sim import format_table, run_sim_bench
        result = run_sim_bench(seconds=args.seconds, sizes=args.sizes)
    elif args.what == "perception":
        from scenenav.app.bench.perception import format_table, run_perception_bench
        result = run_perception_bench(n_frames=args.frames, sizes_px=args.map_sizes,
                                      stride_px=args.stride_px,
                                      gradient_refine_px=args.gradient_refine_px)
    else:
        raise UserError(f"unknown benchmark {args.what!r}")
    if args.json:
        emit_json(result)
    else:
        print(format_table(result), end="")
    return 0


def _table2(args: argparse.Namespace) -> int:
    from scenenav.app.experiment import run_table2
    run_table2(args.world, args.out, seed=args.seed, threshold_m=args.false_fix_threshold_m,
               overrides=tuple(args.set or ()), progress=not args.quiet,
               results_page=args.results_page, realism=args.realism, scripted=args.scripted,
               paper_rows=not args.no_paper_rows)
    return 0


def _relief(args: argparse.Namespace) -> int:
    from scenenav.app.relief_experiment import relief_markdown, run_relief
    doc = run_relief(args.world, args.out, seed=args.seed, positions=args.positions,
                     progress=not args.quiet, window_px=args.window_px)
    if args.json:
        emit_json(doc)
    else:
        print(relief_markdown(doc), end="")
    return 0


def _sitl(args: argparse.Namespace) -> int:
    from scenenav.app.sitl_cmd import SitlOptions, run_sitl
    opts = SitlOptions(scenario=args.scenario, world=args.world, gps=not args.no_gps,
                       speedup=args.speedup, out=args.out, tcp_port=args.tcp_port, tcp_host=args.tcp_host,
                       udp_out=args.udp_out, perception=args.perception, lockstep=args.lockstep,
                       overrides=tuple(args.set or ()), instance=args.instance, wipe=args.wipe,
                       live_port=args.live_port if args.live else None,
                       external=tuple(args.external or ()))
    summary = run_sitl(opts, announce=lambda text: print(text, flush=True))
    from scenenav.app.evaluation import format_summary
    print(format_summary(summary))
    return 0 if not (summary.get("failed_nodes") or summary.get("aborted")) else 1


# Commands defined in this module alone: for these main() leaves out the domain packages' commands,
# whose registration imports torch, scipy and the planner (1.5-2 s of CPU), so the launcher and every
# node of a run (``scenenav node sim ...``) start without them. The parser of each of these commands
# is the same either way; ``scenenav --help`` and every other command get the whole parser.
_OWN_COMMANDS = frozenset({"run", "summarize", "node", "sitl", "experiment"})


def _live_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--live", action="store_true",
                   help="stream the run live to Foxglove: a WebSocket server (foxglove.websocket.v1) "
                        "on 127.0.0.1, camera, fixes, estimate and truth, maps, route, events, "
                        "status; open it in Foxglove with docs/foxglove-layout.json (docs/live-view.md)")
    p.add_argument("--live-port", type=port_number, default=DEFAULT_LIVE_PORT, metavar="N",
                   help=f"with --live: the WebSocket port (default {DEFAULT_LIVE_PORT}, Foxglove's; "
                        "0: any free port; the run folder's live.json names it)")


#: The module under ``scenenav.app.commands`` that registers each domain command: ``scenenav world
#: ...`` imports only the world module (not torch), ``scenenav bench ...`` only the benchmarks.
_DOMAIN_COMMAND_MODULES = {"world": "world", "plan": "plan", "dataset": "perception",
                           "train": "perception", "cnn": "perception",
                           "assistant-map": "assistant_map", "campaign": "campaign"}
_ALL_COMMAND_MODULES = ("world", "plan", "perception", "assistant_map", "campaign")


def build_parser(domain_commands: bool | str = True, bench: str | None = None) -> argparse.ArgumentParser:
    """The ``scenenav`` parser; without ``domain_commands`` only the commands of this module; with a
    command's name, this module's commands and that one (its parser is the same as in the whole
    parser; ``bench`` names the benchmarks, and ``bench`` the one benchmark to register: None, all)."""
    p = argparse.ArgumentParser(
        prog="scenenav",
        description="Software-in-the-loop stack for GPS-denied drone navigation by scene matching: "
                    "a pybullet quadrotor over a textured city, Zenoh nodes, a MAVLink autopilot.",
    )
    p.add_argument("--log-level", default="WARNING",
                   choices=["DEBUG", "INFO", "WARNING", "ERROR"], help="library log level (default WARNING)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser("run", help="fly a scenario headless and write its run folder",
                       description="Start the simulator, recorder, perception (and autopilot) as child "
                                   "processes, fly SCENARIO (YAML; defaults: a scripted loop over the "
                                   "default world) and write RUN_DIR: summary.json, truth/fixes/estimates "
                                   "CSV, trajectory.png, bus.mcap, one log per node. Ctrl-C stops every "
                                   "node cleanly and still writes the summary.")
    r.add_argument("scenario", nargs="?", help="scenario YAML (see docs/scenarios.md)")
    r.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder to create (must be new or empty)")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario key, e.g. --set duration_s=30 --set perception.method=statistical")
    r.add_argument("--external", action="append", metavar="ROLE:ID",
                   help="a node you start yourself (repeatable), e.g. perception:my_matcher: the built-in "
                        "node of that role is not started and the clock waits for yours (external.nodes, "
                        "external.join_timeout_s; it joins with RUN_DIR/run.json, see docs/interfaces.md)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _live_args(r)
    r.set_defaults(func=_run)

    sm = sub.add_parser("summarize", help="rebuild summary.json and trajectory.png of a run folder",
                        description="Rebuild summary.json and trajectory.png of any run folder from what "
                                    "was recorded: a complete run, an interrupted one, or one whose "
                                    "launcher was killed. An unfinished bus.mcap (recorder killed) is "
                                    "finished in place first. The summary lists the files the run did "
                                    "not leave (missing) and says it was rebuilt.")
    sm.add_argument("run_dir", metavar="RUN_DIR", help="run folder (holds scenario.yaml)")
    sm.set_defaults(func=_summarize)

    n = sub.add_parser("node", help="run one node of a run (the launcher uses this), or check yours",
                       description="Run a single bus node. Normally started by `scenenav run` or "
                                   "`scenenav sitl`; start one by hand to swap a node in a live run "
                                   "(same --namespace and --hub-port as the run, see its run.json). "
                                   "`scenenav node check perception -- COMMAND...` checks a node you "
                                   "wrote against the bus contract.")
    nsub = n.add_subparsers(dest="kind", metavar="KIND")
    nsub.required = True
    bus_args = argparse.ArgumentParser(add_help=False)
    bus_args.add_argument("--namespace", required=True, help="key namespace of the run (run.json: namespace)")
    bus_args.add_argument("--hub-port", required=True, type=int,
                          help="the simulator's Zenoh port (run.json: hub_port)")
    bus_args.add_argument("--hub-host", type=ipv4_address, default="127.0.0.1",
                          help="the address of the simulator's machine (run.json: bus.remote_endpoints "
                               "from another machine; default 127.0.0.1)")
    bus_args.add_argument("--listen-host", type=ipv4_address, default="127.0.0.1",
                          help="the address this node listens on for the other nodes (default 127.0.0.1; "
                               "on another machine its own address or 0.0.0.0)")
    bus_args.add_argument("--run-dir", help="run folder (reads scenario.yaml from it)")
    kinds = {"sim": "the simulator (the run's hub and clock)", "recorder": "the recorder (CSV, bus.mcap)",
             "perception": "a perception node (scene-matching fixes)", "autopilot": "the MAVLink autopilot",
             "guidance": "the guidance node (plans and uploads the mission)",
             "live": "the live view (Foxglove WebSocket server)"}
    node_parsers = {kind: nsub.add_parser(kind, parents=[bus_args], help=text, description=f"Run {text}.")
                    for kind, text in kinds.items()}
    node_parsers["sim"].add_argument("--expect", help="comma list of nodes to wait for (recorder,tick,camera)")
    pn = node_parsers["perception"]
    pn.add_argument("--method", choices=["cnn", "assistant-map", "statistical", "none"],
                    help="false-match method (default: the scenario's)")
    pn.add_argument("--node-id", default="perception", help="node id on the bus")
    pn.add_argument("--world", help="world folder (default: the scenario's)")
    pn.add_argument("--assistant-map", help="assistant map .npz")
    pn.add_argument("--lockstep", choices=["on", "off"], help="answer each frame in lockstep")
    node_parsers["live"].add_argument("--live-port", type=port_number, default=DEFAULT_LIVE_PORT,
                                      help=f"WebSocket port (default {DEFAULT_LIVE_PORT}; 0: any free port)")
    for np_ in node_parsers.values():
        np_.set_defaults(func=_node)
    nc = nsub.add_parser(
        "check", help="conformance check of a node you wrote (flies a short lockstep run)",
        description="Fly a short lockstep run that waits for your node (scenenav run --external "
                    "ROLE:ID), start COMMAND once RUN_DIR/run.json exists ({run_dir} and {node_id} in "
                    "COMMAND are replaced; the environment has SCENENAV_RUN_DIR and SCENENAV_NODE_ID), "
                    "send it malformed camera frames part-way, and report pass/fail per rule of "
                    "docs/interfaces.md (section 9): liveliness, acks, fixes, encoding, timestamps, "
                    "fields, covariance, malformed, leaves. Exit code 0 only if every rule passes.",
        usage="scenenav node check ROLE [options] -- COMMAND...",
        epilog="example: scenenav node check perception -- python "
               "examples/perception_node_python/node.py {run_dir}")
    nc.add_argument("role", choices=["perception"], help="the role your node takes")
    nc.add_argument("--node-id", default="node_under_check", help="node id your node must use (default "
                                                                  "node_under_check; run.json lists it)")
    nc.add_argument("--duration-s", type=float, default=10.0, help="simulated seconds of the run (default 10)")
    nc.add_argument("--ack-timeout-s", type=float, default=10.0,
                    help="wall seconds within which every frame must be acknowledged (default 10)")
    nc.add_argument("--scenario", help="scenario YAML to fly (default: the scripted flight over the default world)")
    nc.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scenario key")
    nc.add_argument("--out", metavar="DIR", help="folder for the run, the logs and check.json (default: a "
                                                 "new temporary folder, kept)")
    nc.add_argument("--json", action="store_true", help="print only the JSON report on stdout")
    nc.set_defaults(func=_node_check, command=())

    e = sub.add_parser("experiment", help="the paper's experiments, reproduced",
                       description="Experiments that regenerate the paper's results from flights.")
    esub = e.add_subparsers(dest="experiment", metavar="NAME")
    esub.required = True
    t2 = esub.add_parser("table2", help="Table 2: online CNN, assistant map, statistical, none",
                         description="Fly the same path in lockstep (identical frames) once per method: "
                                     "online CNN (builds the assistant map), the assistant map from "
                                     "that flight, the statistical indicator, no exclusion. CNN and "
                                     "assistant map fly the combined decision rule and, for comparison, "
                                     "again the paper's rule P(bad) > 0.5 with their own map: six "
                                     "flights, flown by the autopilot on GPS (--scripted: the kinematic path). Writes table2.json, table2.md, "
                                     "figure7.png, figure8.png and one run folder per flight.")
    t2.add_argument("--world", help="world folder (default: the built-in default world)")
    t2.add_argument("--out", required=True, metavar="DIR")
    t2.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    t2.add_argument("--false-fix-threshold-m", type=float, default=5.0,
                    help="a fix whose error exceeds this is false (default 5 m)")
    t2.add_argument("--set", action="append", metavar="KEY=VALUE", help="scenario override for every flight")
    t2.add_argument("--quiet", action="store_true", help="no progress bars")
    t2.add_argument("--results-page", metavar="FILE.md",
                    help="also update the results page (e.g. docs/results.md): this run's column "
                         "(its profile and flight kind) beside the tables stored there")
    add_flight_kind_arguments(t2, "the scenario default, ideal", "the old table")
    t2.add_argument("--no-paper-rows", action="store_true",
                    help="skip the two extra flights of the paper's rule (four flights, not six)")
    t2.set_defaults(func=_table2)
    rl = esub.add_parser("relief", help="what relief does to matching: flat vs 3-D captures, ortho vs "
                                        "500 m perspective reference",
                         description="With the perception node's matcher (alignment + NCC, global "
                                     "search) and ideal sensors (true heading and altitude), capture "
                                     "N seeded positions away from the map edge (nadir, 100 m, random "
                                     "heading) three ways: the world rendered flat vs the orthophoto "
                                     "reference, the 3-D city vs the orthophoto reference, the 3-D city "
                                     "vs the perspective reference taken from 500 m. Prints, per "
                                     "comparison, the median error, the RMS of errors up to 5 m, the "
                                     "share over 5 m and over 20 m, each also by mean building height "
                                     "in the footprint; errors are against the truth with the "
                                     "reference misregistration undone. Writes relief.json and "
                                     "relief.md to --out.")
    rl.add_argument("--world", help="world folder, 'default' or 'generated:seed=N,...' (default: the "
                                    "default world)")
    rl.add_argument("--seed", type=nonneg_int, default=0, help="seed of the positions (default 0)")
    rl.add_argument("--positions", type=positive_int,
                    help="number of positions (default 300 on worlds up to the default world's size, "
                         "600 on bigger ones)")
    rl.add_argument("--window-px", type=positive_int, metavar="R",
                    help="search only the template plus R px around the true match (a tracked flight's "
                         "window) instead of the whole map (default: global search)")
    rl.add_argument("--out", metavar="DIR", help="folder for relief.json and relief.md (default: none)")
    rl.add_argument("--json", action="store_true", help="print only the JSON document on stdout")
    rl.add_argument("--quiet", action="store_true", help="no progress bars")
    rl.set_defaults(func=_relief)

    st = sub.add_parser("sitl", help="a simulated vehicle for ground stations (like sim_vehicle.py)",
                        description="Start the simulator, the autopilot (ArduCopter-compatible MAVLink on "
                                    "TCP 127.0.0.1:5760 and UDP out to 127.0.0.1:14550), a perception node "
                                    "and the recorder; the vehicle waits on the ground for a ground "
                                    "station (MAVProxy, QGroundControl, MAVSDK). Runs until Ctrl-C, then "
                                    "writes the run folder. See docs/autopilot.md.")
    st.add_argument("--scenario", help="scenario YAML to start from (world, sensors, start point...)")
    st.add_argument("--world", metavar="DIR", help="world folder (default: the scenario's, else the default world)")
    st.add_argument("--no-gps", action="store_true",
                    help="GPS off: the autopilot navigates on scene-matching fixes (EK3_SRC1_POSXY 6)")
    st.add_argument("--speedup", type=float, default=1.0, metavar="N",
                    help="simulated seconds per wall second (default 1)")
    st.add_argument("--out", metavar="RUN_DIR", help="run folder to create (default runs/sitl-<time>)")
    st.add_argument("--tcp-port", type=int, default=5760,
                    help="MAVLink TCP server port (default 5760; 0 = off)")
    st.add_argument("--tcp-host", type=ipv4_address, default=None,
                    help="address the MAVLink TCP server listens on (default 127.0.0.1, this machine "
                         "only; 0.0.0.0 lets a ground station on another machine connect)")
    st.add_argument("--udp-out", default="127.0.0.1:14550", metavar="HOST:PORT",
                    help="MAVLink UDP output (default 127.0.0.1:14550; 0 or none = off; another "
                         "machine's address sends telemetry there, e.g. to QGroundControl on a laptop)")
    st.add_argument("--perception", choices=["cnn", "assistant-map", "statistical", "none", "off"],
                    help="false-match method of the perception node, or off for no perception node "
                         "(default: the scenario's; 'none' accepts every match)")
    st.add_argument("--lockstep", action="store_true",
                    help="lockstep clock: as fast as the nodes allow, deterministic (default realtime)")
    st.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="override a scenario key, e.g. --set autopilot.params_file=params.json")
    st.add_argument("-I", "--instance", type=int, default=0, metavar="N",
                    help="vehicle instance 0..255: parameters set by a ground station are kept in "
                         "runs/sitl-params/instanceN.json from one start to the next, like "
                         "sim_vehicle.py's eeprom.bin (default 0; ports are not changed: use "
                         "--tcp-port)")
    st.add_argument("-w", "--wipe", action="store_true",
                    help="forget the instance's kept parameters before starting (sim_vehicle.py -w)")
    st.add_argument("--external", action="append", metavar="ROLE:ID",
                    help="a perception or guidance node you start yourself (repeatable), e.g. "
                         "perception:my_matcher: the built-in one is not started and the clock waits for "
                         "yours (external.join_timeout_s); it joins with RUN_DIR/run.json "
                         "(docs/interfaces.md)")
    _live_args(st)
    st.set_defaults(func=_sitl)

    b = sub.add_parser("bench", help="benchmarks that print figures (never part of the tests)",
                       description="Benchmarks. Speed and accuracy targets live here, not in tests.")
    bsub = b.add_subparsers(dest="what", metavar="WHAT")
    bsub.required = True
    bs = bsub.add_parser("sim", help="simulator real-time factor (lockstep, camera 10 Hz) vs world size")
    bs.add_argument("--json", action="store_true", help="print only the results as JSON on stdout")
    bs.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per measurement (default 20)")
    bs.add_argument("--sizes", default="900x1000,2000x2000,8000x8000",
                    help="world sizes WxH in px, comma separated (default 900x1000,2000x2000,8000x8000)")
    bs.set_defaults(func=_bench)
    bp = bsub.add_parser("perception", help="per-fix time by stage and method vs raw matchTemplate",
                         description="Per-fix time (alignment, NCC, CNN, map lookup) for each false-match "
                                     "method on camera frames over the default world, beside a raw "
                                     "cv2.matchTemplate on the same window; whole assistant-map build "
                                     "time; per-fix time as the map grows. One thread (one core).")
    bp.add_argument("--json", action="store_true", help="print only the results as JSON on stdout")
    bp.add_argument("--frames", type=int, default=60, help="camera frames per method (default 60)")
    bp.add_argument("--stride-px", type=positive_int, default=5,
                    help="stride of the whole assistant-map build, px (default 5)")
    bp.add_argument("--map-sizes", type=_side_list, default=(1000, 4000, 8000), metavar="N,N,...",
                    help="square map sides for the per-fix time vs map size, px (default 1000,4000,8000)")
    bp.add_argument("--gradient-refine-px", type=nonneg_int, default=0, metavar="R",
                    help="refine each match on gradient magnitude within R px "
                         "(matcher.gradient_refine_radius_px; the paper and realistic profiles use 24; "
                         "default 0: off, as the ideal profile)")
    bp.set_defaults(func=_bench)
    if domain_commands is True:
        _register_domain_commands(sub, _ALL_COMMAND_MODULES)
        _register_benches(bsub)
    elif domain_commands == "bench":
        _register_benches(bsub, bench)
    elif domain_commands in _DOMAIN_COMMAND_MODULES:
        _register_domain_commands(sub, (_DOMAIN_COMMAND_MODULES[str(domain_commands)],))
    return p


def _register_domain_commands(sub, modules: tuple[str, ...]) -> None:
    """Subcommands of the domain packages (their own modules under app/commands), in the order of
    ``_ALL_COMMAND_MODULES``."""
    import importlib
    for name in modules:
        importlib.import_module(f"scenenav.app.commands.{name}").register(sub)


#: The module under ``scenenav.app.bench`` that registers each benchmark of the domain packages
#: (``sim`` and ``perception`` are defined in this module), in the order of ``scenenav bench --help``.
_BENCH_MODULES = {"plan": "plan", "autopilot": "autopilot", "e2e": "e2e", "campaign": "campaign",
                  "soak": "soak", "render": "render"}
_OWN_BENCHES = frozenset({"sim", "perception"})


def _register_benches(bsub, only: str | None = None) -> None:
    """The benchmarks of the domain packages (their own modules under app/bench): all of them, or
    only the one ``scenenav bench NAME`` names (the others import the EKF, the planner, ...: about
    1 s of CPU a command does not need; its parser is the same either way)."""
    import importlib
    if only in _OWN_BENCHES:
        return
    names = (only,) if only in _BENCH_MODULES else tuple(_BENCH_MODULES)
    for name in names:
        importlib.import_module(f"scenenav.app.bench.{_BENCH_MODULES[name]}").register_bench(bsub)


_NEGATIVE_LIST = re.compile(r"^-\d[\d.eE+-]*(,\s*[-+]?[\d.eE+-]+)+$")


def glue_negative_values(argv: list[str]) -> list[str]:
    """``--start -150,200`` -> ``--start=-150,200``: argparse would take a value that starts with
    '-' and holds a comma for an option. Only comma lists of numbers are glued."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if (a.startswith("--") and "=" not in a and i + 1 < len(argv)
                and _NEGATIVE_LIST.match(argv[i + 1])):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def _side_list(text: str) -> tuple[int, ...]:
    try:
        sides = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated sides in px, e.g. 1000,4000") from None
    if not sides or any(not 256 <= v <= 20000 for v in sides):
        raise argparse.ArgumentTypeError(f"{text!r}: each side must be 256 to 20000 px")
    return sides


def _command_of(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (it follows the global ``--log-level``), or None."""
    i = 0
    while i < len(argv):
        a = argv[i]
        if a == "--log-level":
            i += 2
        elif a.startswith("--log-level="):
            i += 1
        else:
            return None if a.startswith("-") else a
    return None


def split_node_command(argv: list[str]) -> tuple[list[str], tuple[str, ...] | None]:
    """``scenenav node check ... -- COMMAND...``: the arguments before ``--`` and COMMAND (None
    for every other command line); COMMAND is never parsed as options of ours."""
    try:
        i = argv.index("node")
    except ValueError:
        return argv, None
    if argv[i + 1:i + 2] != ["check"] or "--" not in argv[i:]:
        return argv, None
    j = argv.index("--", i)
    return argv[:j], tuple(argv[j + 1:])


def main(argv: list[str] | None = None) -> int:
    argv, node_command = split_node_command(list(sys.argv[1:] if argv is None else argv))
    argv = glue_negative_values(argv)
    command = _command_of(argv)
    if command in _OWN_COMMANDS:
        parser = build_parser(domain_commands=False)
    elif command == "bench":
        parser = build_parser(domain_commands=command, bench=_command_of(argv[argv.index("bench") + 1:]))
    elif command in _DOMAIN_COMMAND_MODULES:
        parser = build_parser(domain_commands=command)
    else:
        parser = build_parser()     # --help, no command, a misspelt one: the whole list
    args = parser.parse_args(argv)
    if node_command is not None:
        args.command = node_command
    logging.basicConfig(level=getattr(logging, args.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_json_aware(args)


if __name__ == "__main__":
    sys.exit(main())
