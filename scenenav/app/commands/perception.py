"""`scenenav dataset`, `scenenav train` and `scenenav cnn {compare,info,bench}` (the paper's CNN).

``register(subparsers)`` is called by ``scenenav.app.cli``; ``python -m scenenav.app.commands.perception ...`` runs the
same commands standalone. Bad input raises ``UserError`` (one line, exit 2).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from scenenav.app.arg_types import add_flight_kind_arguments, nonneg_int, positive_float, positive_int
from scenenav.app.json_output import emit_json, run_json_aware
from scenenav.core.errors import UserError


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT in pixels, e.g. 900x1000") from None
    return w, h


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated integers, e.g. 9001,9002") from None
    if not seeds:
        raise argparse.ArgumentTypeError("expected at least one seed")
    return seeds


def _command_line() -> str:
    """The command as typed (``scenenav ...`` or ``python -m scenenav.app.commands.perception ...``)."""
    if not sys.argv:
        return ""
    prog = "python -m scenenav.app.commands.perception" if sys.argv[0].endswith(("scenenav/app/commands/perception.py", "scenenav.app.commands.perception")) else "scenenav"
    return prog + " " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def _dataset(args: argparse.Namespace) -> int:
    from perception.capture import CaptureSettings
    from perception.cnn_spec import Labelling
    from perception.dataset import build_dataset
    from perception.dataset_config import ArmLabels, CropGeometry, DatasetConfig, IntersectionView
    w, h = args.world_size
    cfg = DatasetConfig(n_worlds=args.worlds, seed=args.seed, labelling=Labelling(args.labelling),
                        base_crops=args.base_crops, augment_to=args.augment_to, world_width_px=w,
                        world_height_px=h, crop=CropGeometry(args.crop),
                        intersection_crop_m=args.intersection_crop_m,
                        intersection_view=IntersectionView(args.intersection_view), arms=ArmLabels(args.arms),
                        capture=CaptureSettings(relief=not args.no_relief, reference=args.reference))
    man = build_dataset(args.out, cfg, progress=not args.quiet, command=_command_line())
    print(f"dataset {args.out}: {man['n_images']} images ({man['n_base_crops']} base crops), "
          f"labelling {man['labelling']}, counts {man['counts']}, worlds {man['world_seeds']}, "
          f"{man['wall_time_s']['total']:.0f} s")
    return 0


def _train(args: argparse.Namespace) -> int:
    import numpy as np

    from perception.training import TrainConfig, format_confusion, train
    cfg = TrainConfig(epochs=args.epochs, seed=args.seed, input_px=args.input_px, batch_size=args.batch_size,
                      num_threads=args.threads, split=args.split)
    res = train(args.data, args.out, cfg, progress=not args.quiet, command=_command_line(),
                extra_train=tuple(args.extra_train or ()))
    fin = res.record["final"]
    print(f"training   accuracy {fin['train_accuracy']:.3f} loss {fin['train_loss']:.3f}   (paper Table 1: 0.96 / 0.08)")
    print(f"validation accuracy {fin['val_accuracy']:.3f} loss {fin['val_loss']:.3f}   (paper Table 1: 0.92 / 0.10)")
    print("validation confusion matrix:")
    print(format_confusion(np.array(res.record["confusion_matrix"]["counts"])))
    print(f"weights {res.weights_path}, record {res.record_path}, confusion {res.confusion_png} "
          f"({res.record['wall_time_s']['total']:.0f} s)")
    return 0


def _compare(args: argparse.Namespace) -> int:
    from perception.training import CompareConfig, compare_labellings
    cfg = CompareConfig(eval_world_seeds=args.eval_worlds, uniform_positions_per_world=args.positions,
                        captures_per_position=args.captures, seed=args.seed, epochs=args.epochs,
                        input_px=args.input_px, num_threads=args.threads)
    report = compare_labellings(args.paper_data, args.matchability_data, args.out, cfg,
                                paper_weights=args.paper_weights, matchability_weights=args.matchability_weights,
                                progress=not args.quiet)
    print((Path(args.out) / "compare_report.md").read_text(encoding="utf-8"))
    print(f"report: {Path(args.out) / 'compare_report.json'} ({report['wall_time_s']} s)")
    return 0


def _info(args: argparse.Namespace) -> int:
    from perception.cnn import load_weights
    from perception.training import sidecar_paths
    path = Path(args.weights)
    model, meta = load_weights(path)
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB, input {meta.input_px} px, labelling {meta.labelling}, "
          f"record {meta.training_record_id}, classes {list(meta.classes)}")
    print(f"{'layer':<10}{'type':<12}{'output shape':<18}{'params':>10}")
    for name, kind, shape, n in model.layer_table():
        print(f"{name:<10}{kind:<12}{str(shape):<18}{n:>10}")
    print(f"total parameters: {sum(p.numel() for p in model.parameters())}")
    rec_path, _ = sidecar_paths(path)
    if rec_path.is_file():
        try:
            rec = json.loads(rec_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise UserError(f"{rec_path}: not valid JSON ({exc.msg})") from None
        fin = rec.get("final", {})
        if rec.get("record_id") == meta.training_record_id:
            print(f"training record {rec_path}: train acc {fin.get('train_accuracy', float('nan')):.3f} "
                  f"loss {fin.get('train_loss', float('nan')):.3f}, val acc {fin.get('val_accuracy', float('nan')):.3f} "
                  f"loss {fin.get('val_loss', float('nan')):.3f}; command: {rec.get('command', '')}")
        else:
            print(f"training record {rec_path} belongs to another model ({rec.get('record_id')})")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from perception.cnn import MatchClassifier, benchmark
    clf = (MatchClassifier.from_file(args.weights, num_threads=args.threads) if args.weights
           else MatchClassifier.default(num_threads=args.threads))
    res = benchmark(clf, crop_px=args.crop_px, n_batch=args.n, repeats=args.repeats)
    if args.json:
        emit_json(res)
    else:
        print(f"one image ({args.crop_px} px): {res['single_image_ms']:.2f} ms; batch of {args.n}: "
              f"{res['batch_ms_per_image']:.3f} ms/image best, {res['batch_ms_per_image_median']:.3f} median "
              f"-> 36k crops {res['projected_36k_crops_s']:.1f} s best, {res['projected_36k_crops_s_median']:.1f} s "
              f"median ({int(res['threads'])} thread(s))")
    return 0


def _decision_data(args: argparse.Namespace) -> int:
    from scenenav.app.decision_data import collect
    runs = collect(args.out, args.worlds, args.world_size, args.weights or "", progress=not args.quiet,
                   command=_command_line(), realism=args.realism, scripted=args.scripted,
                   overrides=tuple(args.set or ()))
    kind = "scripted" if args.scripted else "autopilot"
    print(f"decision data {args.out}: {len(runs)} cnn flights ({args.realism or 'ideal'}, {kind}): "
          + ", ".join(str(r) for r in runs))
    return 0


def _fit_decision(args: argparse.Namespace) -> int:
    from scenenav.app.decision_data import evaluate_flights, fit_decision, flight_dirs_under
    flights = flight_dirs_under(args.data)
    man_path = Path(args.data) / "manifest.json"
    manifest = json.loads(man_path.read_text(encoding="utf-8")) if man_path.is_file() else None
    model = fit_decision(flights, args.out, args.weights, l2=args.l2,
                         target_recall=args.target_recall, command=_command_line(),
                         data_manifest=manifest)
    cv = model.meta["cross_validation"]
    print(f"decision model {args.out} ({model.model_id}): threshold {model.threshold:.4g}, "
          f"{model.meta['samples']} samples ({model.meta['false_samples']} false) from "
          f"{len(flights)} training flights")
    for src, sc in cv.items():
        c = sc["t=chosen"]
        print(f"  leave-one-world-out {src:<14} precision {c['precision']:.3f} recall {c['recall']:.3f} "
              f"rms accepted {c['rms_accepted_m']:.2f} m")
    if args.eval:
        res = evaluate_flights(model, flight_dirs_under(args.eval))
        for world, row in res.items():
            for src, r in row.items():
                c, pp = r["combined"], r["paper"]
                print(f"  held-out {world:<10} {src:<14} combined P {c['precision']:.3f} R {c['recall']:.3f} "
                      f"| paper P {pp['precision']:.3f} R {pp['recall']:.3f}")
    return 0


def register(subparsers) -> None:
    """Add `dataset`, `train` and `cnn` to the scenenav command."""
    from perception.cnn_spec import DEFAULT_INPUT_PX
    from perception.dataset_config import EVAL_WORLD_SEEDS, DatasetConfig
    from perception.training_config import CompareConfig, TrainConfig
    dc, tc, cc = DatasetConfig(), TrainConfig(), CompareConfig()

    d = subparsers.add_parser(
        "dataset", help="build the labelled good/bad matching-area dataset from generated worlds",
        description="Generate N worlds and cut camera-footprint crops from their orthophotos: centred on "
                    "junctions (class by arm count) and on areas dominated by bad matching covers (water, "
                    "forest, grass, squares, uniform roofs), as in the paper (section 5.2); grayscale, 200x200 "
                    "PNG under DIR/images/<CLASS>/, augmented to --augment-to images, with index.csv and "
                    "manifest.json. --labelling matchability labels these positions plus 2000 random ones by "
                    "simulated NCC success (BAD when < 50 % of noisy captures match within 5 m; see "
                    "docs/cnn.md). World seeds 9001, 9002 are reserved for evaluation.")
    d.add_argument("--out", required=True, metavar="DIR", help="dataset folder to create (new or empty)")
    d.add_argument("--worlds", type=positive_int, default=dc.n_worlds, help=f"number of worlds (default {dc.n_worlds})")
    d.add_argument("--seed", type=nonneg_int, default=dc.seed,
                   help="dataset seed; world seeds are 1 + 1000*seed + i (default 0)")
    d.add_argument("--labelling", choices=["paper", "matchability"], default=dc.labelling.value,
                   help="paper: junction arms / bad land cover; matchability: simulated NCC success (default paper)")
    d.add_argument("--base-crops", type=positive_int, default=dc.base_crops,
                   help=f"base crops before augmentation (default {dc.base_crops}, the paper's 1500)")
    d.add_argument("--augment-to", type=positive_int, default=dc.augment_to,
                   help=f"total images after augmentation (default {dc.augment_to}, the paper's 3920)")
    d.add_argument("--world-size", type=_size, default=(dc.world_width_px, dc.world_height_px), metavar="WxH",
                   help=f"world size in px (default {dc.world_width_px}x{dc.world_height_px})")
    d.add_argument("--crop", choices=["footprint", "intersection"], default=dc.crop.value,
                   help="footprint: the camera footprint at 100 m (217 px = 115 m, what the network sees in "
                        "flight; several junctions in a city grid); intersection: the paper's crops of single "
                        "intersections, a --intersection-crop-m square with no other junction inside "
                        "(paper labelling only; docs/cnn.md compares both) (default footprint)")
    d.add_argument("--intersection-crop-m", type=positive_float, default=dc.intersection_crop_m, metavar="M",
                   help=f"side of an intersection crop in metres (default {dc.intersection_crop_m:g})")
    d.add_argument("--intersection-view", choices=["crop", "flight"], default=dc.intersection_view.value,
                   help="with --crop intersection on a relief world: crop = the nadir camera whose 60 deg "
                        "footprint is the crop (about 43 m up for 50 m: roofs lean far over the streets); "
                        "flight = the central square of the flight camera's image at 100 m, the junction as "
                        f"the drone sees it (default {dc.intersection_view.value})")
    d.add_argument("--arms", choices=["graph", "visible"], default=dc.arms.value,
                   help="with --crop intersection: graph = every junction, labelled by its road-graph arm "
                        "count; visible = only junctions whose crop shows that many arms in the road raster "
                        "(roads from the junction reaching 45 %% of the crop side from the centre, no square "
                        "or parking lot filling the ring), as labelling by eye would; the manifest counts "
                        f"the dropped ones (default {dc.arms.value})")
    d.add_argument("--no-relief", action="store_true",
                   help="flat crops of the orthophoto even where the world has a DSM (default: nadir "
                        "captures rendered with relief there; flat worlds give the same images either way)")
    d.add_argument("--reference", choices=["default", "orthophoto", "perspective"], default="default",
                   help="reference map the matchability labelling matches against (default: the one "
                        "the world's manifest names)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_dataset)

    t = subparsers.add_parser(
        "train", help="train the paper's CNN on a dataset folder",
        description="Train the paper's CNN (2 conv + 2 avg-pool + 2 FC/dropout + softmax) with Adam and "
                    "cross-entropy on an 80/20 seeded, stratified, spatially grouped split. Prints training and "
                    "validation accuracy/loss per epoch and the confusion matrix; writes WEIGHTS.pt, "
                    "training_record.json and confusion_matrix.png beside it (prefixed with the file stem "
                    "unless it is default.pt).")
    t.add_argument("--data", required=True, metavar="DIR", help="dataset folder written by `scenenav dataset`")
    t.add_argument("--out", required=True, metavar="WEIGHTS.pt", help="weights file to write")
    t.add_argument("--epochs", type=positive_int, default=tc.epochs, help=f"epochs (default {tc.epochs})")
    t.add_argument("--seed", type=nonneg_int, default=tc.seed, help="seed of split, init and order (default 0)")
    t.add_argument("--input-px", type=positive_int, default=tc.input_px,
                   help=f"network input side in px (default {DEFAULT_INPUT_PX}; the paper: 200)")
    t.add_argument("--batch-size", type=positive_int, default=tc.batch_size, help=f"default {tc.batch_size}")
    t.add_argument("--threads", type=positive_int, default=tc.num_threads, help="torch threads, 1 or 2 (default 2)")
    t.add_argument("--split", choices=["grouped", "random"], default=tc.split,
                   help="grouped: whole spatial tiles (default, no augmented copy on both sides); random: "
                        "image-level like a plain Keras validation split")
    t.add_argument("--extra-train", action="append", metavar="DIR",
                   help="another `scenenav dataset` folder, of other worlds (no world seed shared with --data; "
                        "same labelling and crop size), added to the training side only: the split of --data, "
                        "hence the validation set, stays the same (repeatable)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=_train)

    c = subparsers.add_parser("cnn", help="inspect, benchmark and compare CNN models",
                              description="Tools around the good/bad matching-area CNN.")
    csub = c.add_subparsers(dest="cnn_command", metavar="ACTION")
    csub.required = True
    cp = csub.add_parser(
        "compare", help="paper vs matchability labelling on held-out worlds",
        description="Train (or load) one model per labelling and measure on held-out worlds how well P(bad) "
                    "predicts false matches (a simulated capture whose NCC peak lands > 5 m from the truth): "
                    "AUC and precision/recall of 'reject when P(bad) > 0.5', for the online capture and the "
                    "assistant-map (reference crop) inputs. Writes compare_report.json and .md.")
    cp.add_argument("--paper-data", required=True, metavar="DIR1", help="dataset built with --labelling paper")
    cp.add_argument("--matchability-data", required=True, metavar="DIR2",
                    help="dataset built with --labelling matchability")
    cp.add_argument("--eval-worlds", type=_seeds, default=EVAL_WORLD_SEEDS, metavar="SEEDS",
                    help="held-out world seeds, comma separated (default 9001,9002)")
    cp.add_argument("--out", default="runs/cnn_compare", metavar="DIR", help="report folder (default runs/cnn_compare)")
    cp.add_argument("--paper-weights", metavar="PT", help="use these weights instead of training on DIR1")
    cp.add_argument("--matchability-weights", metavar="PT", help="use these weights instead of training on DIR2")
    cp.add_argument("--epochs", type=positive_int, default=cc.epochs, help=f"epochs when training (default {cc.epochs})")
    cp.add_argument("--input-px", type=positive_int, default=cc.input_px, help="input px when training")
    cp.add_argument("--positions", type=positive_int, default=cc.uniform_positions_per_world,
                    help=f"uniform positions per world (default {cc.uniform_positions_per_world})")
    cp.add_argument("--captures", type=positive_int, default=cc.captures_per_position,
                    help=f"simulated captures per position (default {cc.captures_per_position})")
    cp.add_argument("--seed", type=nonneg_int, default=cc.seed, help="evaluation seed (default 0)")
    cp.add_argument("--threads", type=positive_int, default=cc.num_threads, help="torch threads (default 2)")
    cp.add_argument("--quiet", action="store_true", help="no progress bars")
    cp.set_defaults(func=_compare)

    ci = csub.add_parser("info", help="print a weights file's metadata, layer table and training figures",
                         description="Load WEIGHTS (.pt from `scenenav train`) and print its metadata, the layer "
                                     "table with output shapes and parameter counts, and its training record.")
    ci.add_argument("weights", metavar="WEIGHTS", help="weights file (.pt)")
    ci.set_defaults(func=_info)

    cb = csub.add_parser("bench", help="CNN inference speed (one image and a batch)",
                         description="Time one-image and batched inference (random crops resized inside).")
    cb.add_argument("weights", nargs="?", metavar="WEIGHTS", help="weights file (default: the shipped weights)")
    cb.add_argument("--threads", type=positive_int, default=1, help="torch threads (default 1)")
    cb.add_argument("--n", type=positive_int, default=1000, help="crops per timed batch (default 1000)")
    cb.add_argument("--repeats", type=positive_int, default=3, help="timed passes, best and median reported (default 3)")
    cb.add_argument("--crop-px", type=positive_int, default=217, help="crop side in px (default 217)")
    cb.add_argument("--json", action="store_true", help="print only JSON on stdout")
    cb.set_defaults(func=_bench)

    from scenenav.app.decision_data import DEFAULT_TRAIN_SEEDS, HELD_OUT_FROM
    dd = csub.add_parser(
        "decision-data", help="fly training worlds with the online CNN (data for fit-decision)",
        description="Generate each training world (seeded) and fly the Table-2 flight over it once with "
                    "method cnn, exactly as `scenenav experiment table2` flies it (a full lockstep "
                    "`scenenav run`): by default the autopilot mission on GPS, on the --realism profile, "
                    "with the --set overrides last; --scripted flies the old kinematic path (the data "
                    "of the first fits). One world at a time; a finished flight is kept and skipped when "
                    "the command is run again. The run folders (fixes.csv, perception_diag_perception.csv, "
                    "assistant map) and manifest.json are the combined rule's training data "
                    "(`scenenav cnn fit-decision --data DIR`). Seed 0 (the default world) and every "
                    f"seed >= {HELD_OUT_FROM} (held out for blind checks) are refused.")
    dd.add_argument("--out", required=True, metavar="DIR", help="data folder (worlds/ and flights/)")
    dd.add_argument("--worlds", type=_seeds, default=DEFAULT_TRAIN_SEEDS, metavar="SEEDS",
                    help="training world seeds (default " + ",".join(map(str, DEFAULT_TRAIN_SEEDS)) + ")")
    dd.add_argument("--world-size", type=_size, default=(900, 1000), metavar="WxH",
                    help="world size in px (default 900x1000, the paper's map)")
    dd.add_argument("--weights", metavar="PT", help="CNN weights (default: the shipped default.pt)")
    add_flight_kind_arguments(dd, "none given, i.e. ideal, as the first fits", "the old decision data")
    dd.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="scenario override for every flight, laid over everything (repeatable)")
    dd.add_argument("--quiet", action="store_true", help="no progress bars")
    dd.set_defaults(func=_decision_data)

    fd = csub.add_parser(
        "fit-decision", help="fit the combined decision rule on training flights",
        description="Fit the combined rule's logistic P(false fix) on the flights under DATA (from "
                    "`scenenav cnn decision-data`): leave-one-world-out cross-validation picks the "
                    "threshold (largest with pooled out-of-world recall >= --target-recall), then one "
                    "fit on all flights. Writes the decision-model JSON (coefficients, threshold, CNN "
                    "weights it belongs to, fit record). --eval scores it on other flights.")
    fd.add_argument("--data", required=True, metavar="DIR", help="folder written by decision-data")
    fd.add_argument("--out", required=True, metavar="MODEL.json", help="decision model to write")
    fd.add_argument("--weights", required=True, metavar="PT",
                    help="the CNN weights the flights used (recorded relative to the model file)")
    fd.add_argument("--l2", type=float, default=1.0, help="L2 penalty on standardised weights (default 1)")
    fd.add_argument("--target-recall", type=float, default=0.987,
                    help="pooled out-of-world recall the threshold must reach (default 0.987, the "
                         "issue's target)")
    fd.add_argument("--eval", metavar="DIR", help="score the model on the flights under DIR as well")
    fd.set_defaults(func=_fit_decision)


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m scenenav.app.commands.perception {dataset,train,cnn} ...``."""
    import logging
    parser = argparse.ArgumentParser(prog="python -m scenenav.app.commands.perception", description=__doc__)
    parser.add_argument("--log-level", default="WARNING", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    register(sub)
    args = parser.parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_json_aware(args)


if __name__ == "__main__":
    sys.exit(main())
