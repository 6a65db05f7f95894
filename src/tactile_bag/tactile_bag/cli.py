"""`tactile-bag`: record the tactile graph into rosbag2 (MCAP) bags, replay them, evaluate them offline.

    tactile-bag record OUT --duration S [--topics T ...]     camera images, bundles, estimate, ground truth
    tactile-bag play BAG [--rate R] [--loop] [--topics T ...]
    tactile-bag eval BAG [--model DIR] [--json]               metrics against the recorded ground truth

record and eval take --namespace NS for a sensor's graph run in a namespace (its topics /NS/tactile/...).

Bad input (a missing or damaged bag, an unknown topic, a bag without camera images, a model that does not fit
the sensor) ends with one line on stderr and exit status 2. docs/bags.md has the details.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import rclpy

from tactile_bag.evaluate import MATCH_TOLERANCE_S, REFERENCE_BUNDLES, SOURCES, check_fits, evaluate_bag
from tactile_bag.play import MIN_RATE, play
from tactile_bag.record import record
from tactile_bag.topics import IMAGE_TYPE, absolute_topic, default_record_topics, other_sensor_hint, stack_topics
from tactile_conversions.stop_signals import init_ros, stopped_by_signal
from tactile_conversions.topics import GROUND_TRUTH_TOPIC, in_namespace, namespace_argument
from tactile_description import load_sensor
from tactile_description.command_line import (
    ArgumentParser,
    StopSignal,
    error_exit,
    number_argument,
    stop_signals_raised,
    stops_quietly_on_closed_pipe,
    whole_number_argument,
)
from tactile_fusion.live_estimation import MAX_REFERENCE_BUNDLES
from tactile_fusion.metrics import CONTACT_LEVEL_N, contact_level_argument, contact_table, metrics_table


def cmd_record(args) -> int:
    sensor = load_sensor(args.sensor)
    topics = args.topics or default_record_topics(sensor, args.namespace)
    known = stack_topics(sensor, args.namespace)
    init_ros()
    started = time.monotonic()
    try:
        recording = record(args.out, topics, known, args.duration, args.discovery_timeout, args.wait)
    except (KeyboardInterrupt, Exception) as exc:
        if not stopped_by_signal(exc):
            raise
        # record() itself ends on a signal once it records; this is one before then, or a second one meanwhile
        print(f"tactile-bag record: stopped; {args.out} holds what was recorded by then, if it was created",
              file=sys.stderr)
        return 1
    finally:
        rclpy.try_shutdown()
    counts = recording.counts
    total = sum(counts.values())
    silent = [t for t, n in counts.items() if not n]
    # --duration counts from the first message; the time here includes the wait for it
    print(f"recorded {total} messages in {time.monotonic() - started:.1f} s, the wait for the first included, into "
          f"{args.out}: "
          + ", ".join(f"{t} {n}" for t, n in counts.items())
          + (f" (nothing received on {', '.join(silent)})" if silent else ""))
    silent_images = [t for t in silent if known.get(t) == IMAGE_TYPE]
    if silent_images and recording.other_images:
        print(f"tactile-bag record: images are published on {', '.join(recording.other_images)}, not recorded: "
              f"{other_sensor_hint(sensor)}", file=sys.stderr)
    for topic in recording.best_effort_topics:
        print(f"tactile-bag record: {topic}: a best-effort publisher matched no reliable subscription; the topic was "
              "subscribed anew, best effort, to take its messages too from then on (those sent while the new "
              "subscription was matched are not in the bag)", file=sys.stderr)
    if not total and recording.stopped:  # not "no message within --wait": that had not run out (found in review)
        print("tactile-bag record: stopped before any message arrived", file=sys.stderr)
    elif not total:
        print(f"tactile-bag record: no message within {args.wait:g} s: is the graph running, in this "
              "ROS_DOMAIN_ID?", file=sys.stderr)
    return 0 if total else 1


def cmd_play(args) -> int:
    init_ros()
    started = time.monotonic()
    try:
        counts = play(args.bag, args.rate, args.loop, args.topics, args.wait_subscribers)
    except (KeyboardInterrupt, Exception) as exc:
        if not stopped_by_signal(exc):
            raise
        print("tactile-bag play: stopped", file=sys.stderr)  # before playback began (play() reports one after)
        return 1
    finally:
        rclpy.try_shutdown()
    print(f"played {sum(counts.values())} messages in {time.monotonic() - started:.1f} s from {args.bag}: "
          + ", ".join(f"{t} {n}" for t, n in counts.items()))
    return 0


def cmd_eval(args) -> int:
    # Imported here: the model stack (torch, onnxruntime) takes seconds to import and record/play do not need it.
    from tactile_fusion.artifacts import sensor_changes, sensor_changes_warning
    from tactile_fusion.inference import load_predictor

    sensor = load_sensor(args.sensor)
    predictor = load_predictor(args.model, args.backend)
    # `is not None`: an empty --truth-topic is refused (absolute_topic), not taken for the default (review)
    simulator_truth = in_namespace(GROUND_TRUTH_TOPIC, args.namespace)
    named_truth = absolute_topic(args.truth_topic, simulator_truth) if args.truth_topic is not None else None
    truth_topic = named_truth or simulator_truth
    check_fits(predictor, sensor)  # before the warning, which would name the cameras of a model of others
    changes = sensor_changes(predictor.made_for, sensor)
    warning = sensor_changes_warning(changes, sensor)
    if warning:
        print(f"tactile-bag eval: warning: {warning}", file=sys.stderr)
    result = evaluate_bag(args.bag, sensor, predictor, args.source, args.reference_bundles,
                          named_truth, contact_level_n=args.contact_level, namespace=args.namespace)
    summary = {**result.summary(), "sensor_changes": changes}
    if summary["other_image_topics"]:
        print(f"tactile-bag eval: the bag also holds images on {', '.join(summary['other_image_topics'])}, not "
              f"evaluated: {other_sensor_hint(sensor)}", file=sys.stderr)
    if args.json:
        print(json.dumps(summary))
        return 0
    origin = "camera images" if result.source == "images" else "recorded bundles"
    if summary["cameras_without_reference"]:  # live_estimation.ReferenceFrames' patience: taken without them
        reference = (f"the last {summary['reference_bundles']} of the first bundles (fewer complete ones came) "
                     f"averaged into the reference frames without {', '.join(summary['cameras_without_reference'])}")
    else:
        reference = f"the first {summary['reference_bundles']} complete ones averaged into the reference frames"
    print(f"{args.bag}: {summary['bundles']} bundles from {origin}, {reference}; "
          f"{summary['estimates']} estimates ({summary['degraded_estimates']} without every camera)")
    if summary["skipped"]:
        print("skipped: " + ", ".join(f"{reason} {n}" for reason, n in summary["skipped"].items()))
    if summary["cameras_without_reference"]:
        print(f"the reference frames were taken without {', '.join(summary['cameras_without_reference'])} (no usable "
              "image in the first bundles): their images were not used")
    if summary["off_reference_camera_ids"]:
        print(f"{summary['estimates_off_reference']} estimates while {', '.join(summary['off_reference_camera_ids'])} "
              "no longer matched the reference frames (a camera moved or was refocused, or the gel aged, after the "
              "first bundles): those estimates err several times more; record the rest at the start again")
    totals = summary["estimated_total_n"]
    if totals:
        print("estimated total force, N (Fx, Fy, Fz): mean " + _triple(totals["mean"]) + "  min "
              + _triple(totals["min"]) + "  max " + _triple(totals["max"]))
    if summary["matched_with_ground_truth"]:
        print(f"{summary['matched_with_ground_truth']} estimates matched with ground truth "
              f"({summary['ground_truth_messages']} messages on {truth_topic}):")
        metrics = result.metrics
        print(metrics_table({Path(result.bag).name: metrics}))
        print(contact_table({Path(result.bag).name: metrics["contact"]}))
    elif summary["ground_truth_messages"]:
        print(f"no estimate lies within {MATCH_TOLERANCE_S * 1e3:g} ms of the {summary['ground_truth_messages']} "
              f"ground-truth messages on {truth_topic}: estimate statistics only")
    else:
        print(f"no ground truth in the bag ({truth_topic}): estimate statistics only")
    return 0


def _triple(values) -> str:
    return "(" + ", ".join(f"{v:+.4f}" for v in values) + ")"


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="tactile-bag", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sensor_help = "sensor description YAML (default: the installed one, or $TACTILE_SENSOR_CONFIG)"
    namespace_help = ("namespace of the sensor's graph (e.g. left: its topics /left/tactile/...; default: the root "
                      "namespace)")

    rec = sub.add_parser("record", help="record topics of the live graph into a new MCAP bag")
    rec.add_argument("out", help="bag directory to create (must not exist)")
    rec.add_argument("--duration", type=number_argument(0.0, "seconds"), required=True,
                     help="seconds to record, from the first message received (Ctrl-C stops earlier)")
    rec.add_argument("--wait", type=number_argument(0.0, "seconds"), default=10.0, metavar="S",
                     help="give up when no message arrives within S seconds (default 10)")
    rec.add_argument("--topics", nargs="+", metavar="TOPIC",
                     help="topics to record (default: every camera's images, the bundles, the estimate and the "
                          "ground truth)")
    rec.add_argument("--sensor", default=None, help=sensor_help)
    rec.add_argument("--namespace", type=namespace_argument, default="/", help=namespace_help)
    rec.add_argument("--discovery-timeout", type=number_argument(0.0, "seconds", inclusive=True), default=2.0,
                     metavar="S",
                     help="how long to wait for a publisher of a topic outside the stack, to learn its type "
                          "(default 2)")
    rec.set_defaults(run=cmd_record)

    ply = sub.add_parser("play", help="republish a bag's messages with their recorded timing")
    ply.add_argument("bag", help="bag directory")
    ply.add_argument("--rate", type=number_argument(MIN_RATE, "times the recorded speed", inclusive=True), default=1.0,
                     help=f"speed factor, at least {MIN_RATE:g} (default 1: as recorded)")
    ply.add_argument("--loop", action="store_true", help="start over at the end, until Ctrl-C")
    ply.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics (default: all)")
    ply.add_argument("--wait-subscribers", type=number_argument(0.0, "seconds", inclusive=True), default=1.0,
                     metavar="S",
                     help="wait up to S seconds for every topic to have a subscriber before the first message "
                          "(default 1)")
    ply.set_defaults(run=cmd_play)

    ev = sub.add_parser("eval", help="estimate the forces of a bag offline and compare with its ground truth")
    ev.add_argument("bag", help="bag directory")
    ev.add_argument("--model", default=None, help="trained model directory (default: the shipped model)")
    ev.add_argument("--backend", default="onnxruntime", choices=("onnxruntime", "torch"),
                    help="inference backend (default onnxruntime, float32)")
    ev.add_argument("--sensor", default=None, help=sensor_help)
    ev.add_argument("--namespace", type=namespace_argument, default="/", help=namespace_help)
    ev.add_argument("--source", default="auto", choices=SOURCES,
                    help="bundle the camera images (images), take the recorded bundles (bundles), or images when "
                         "the bag has every camera's (auto, default)")
    ev.add_argument("--reference-bundles", type=whole_number_argument(1, "bundles", maximum=MAX_REFERENCE_BUNDLES),
                    default=REFERENCE_BUNDLES,
                    metavar="N",
                    help=f"complete bundles averaged into the reference frames, as fusion_node (default "
                         f"{REFERENCE_BUNDLES}, at most {MAX_REFERENCE_BUNDLES})")
    ev.add_argument("--truth-topic", default=None,
                    help=f"ground truth topic; it must be in the bag (default {GROUND_TRUTH_TOPIC} in --namespace, "
                         "if there)")
    ev.add_argument("--json", action="store_true", help="print one JSON object")
    ev.add_argument("--contact-level", type=contact_level_argument, default=CONTACT_LEVEL_N, metavar="NEWTONS",
                    help="an estimated total Fz from which an estimate counts as reporting contact (default "
                    "%(default)s)")
    ev.set_defaults(run=cmd_eval)
    return parser


@stops_quietly_on_closed_pipe
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # record and play stop on rclpy's handlers (stop_signals); eval runs no ROS, and a Ctrl-C there (loading the model,
    # estimating) gave a KeyboardInterrupt traceback, a SIGTERM an end without a word.
    stop_signals = stop_signals_raised() if args.run is cmd_eval else contextlib.nullcontext()
    try:
        with stop_signals:
            return args.run(args)
    except (ValueError, FloatingPointError) as exc:  # BagError, MessageTypeError, SensorConfigError, ModelFileError,
        return error_exit(f"tactile-bag {args.command}", exc)  # bad arguments; a model that outputs NaN or Inf
    except StopSignal as stop:
        print(f"tactile-bag {args.command}: stopped by {stop.named}", file=sys.stderr)
        return stop.exit_status


if __name__ == "__main__":
    sys.exit(main())
