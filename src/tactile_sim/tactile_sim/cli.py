"""`tactile-sim`: the simulator from the command line.

    tactile-sim press --x-mm 24.5 --y-mm 25.5 --depth-mm 1.5 --json   ground truth of one press
    tactile-sim generate --scene paper_grid --out data/paper_grid     write a data set (docs/simulator.md)
    tactile-sim render --scene multi_contact --out previews           PNG previews of a few frames
    tactile-sim bench --json                                          speed (frames per second, effect costs)

Every command takes --sensor FILE (default: the installed config/sensor.yaml, or $TACTILE_SENSOR_CONFIG);
a scene is a YAML file or the name of an installed one.
"""

from __future__ import annotations

import argparse
import json
import sys

from tactile_description import SensorConfigError, load_sensor
from tactile_description.command_line import (
    ArgumentParser,
    StopSignal,
    error_exit,
    stop_signals_raised,
    stops_quietly_on_closed_pipe,
    whole_number_argument,
)
from tactile_sim.contact import GROUND_TRUTH_MODELS, ground_truth_model, press_contact, press_report
from tactile_sim.dataset import DatasetError, write_dataset
from tactile_sim.effects import SceneError
from tactile_sim.scene import MAX_FRAMES, load_scene


def _model_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", choices=GROUND_TRUTH_MODELS, default=GROUND_TRUTH_MODELS[0],
                        help="ground-truth model")


def build_parser() -> argparse.ArgumentParser:
    # Counts on the command line: 1 to MAX_FRAMES.
    frames, previews, runs = (whole_number_argument(1, unit, maximum=MAX_FRAMES) for unit in ("frames", "previews",
                                                                                                "runs"))
    common = ArgumentParser(add_help=False)
    common.add_argument("--sensor", help="sensor description YAML (default: the installed config/sensor.yaml)")
    parser = ArgumentParser(prog="tactile-sim", description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    press = commands.add_parser("press", parents=[common], help="ground-truth bin forces of one press")
    press.add_argument("--x-mm", type=float, required=True, help="contact centre x (mm, along the columns)")
    press.add_argument("--y-mm", type=float, required=True, help="contact centre y (mm, along the rows)")
    press.add_argument("--depth-mm", type=float, required=True, help="indentation depth (mm)")
    press.add_argument("--shape", choices=("sphere", "punch"), default="sphere")
    press.add_argument("--radius-mm", type=float, help="indenter radius (mm; default sphere: 5, punch: required)")
    press.add_argument("--shear-x-mm", type=float, default=0.0, help="tangential displacement along x (mm)")
    press.add_argument("--shear-y-mm", type=float, default=0.0, help="tangential displacement along y (mm)")
    press.add_argument("--friction", type=float, default=1.0, help="Coulomb friction coefficient")
    _model_option(press)
    press.add_argument("--json", action="store_true", help="print the full report as JSON")

    generate = commands.add_parser("generate", parents=[common], help="write a data set of a scene")
    generate.add_argument("--scene", default="paper_grid", help="scene file or installed scene name")
    generate.add_argument("--out", required=True, help="output directory (new or empty, or see --overwrite)")
    generate.add_argument("--frames", type=frames, help="only the first N frames")
    _model_option(generate)
    generate.add_argument("--overwrite", action="store_true",
                          help="replace the data set's files in an --out that holds one, complete or not; its other "
                          "files stay (refused for a non-empty --out without a data set)")
    generate.add_argument("--no-progress", action="store_true", help="no progress bar")

    render = commands.add_parser("render", parents=[common], help="PNG previews of a scene")
    render.add_argument("--scene", default="paper_grid", help="scene file or installed scene name")
    render.add_argument("--out", required=True, help="output directory")
    render.add_argument("--frames", type=frames, help="only the first N frames of the scene")
    render.add_argument("--count", type=previews, default=8, help="previews, spread evenly (default 8)")
    _model_option(render)

    bench = commands.add_parser("bench", parents=[common], help="speed of the simulator")
    bench.add_argument("--scene", default="paper_grid", help="scene whose presses are timed (default paper_grid)")
    bench.add_argument("--frames", type=frames, help="time only the first N press frames (default all)")
    bench.add_argument("--runs", type=runs, default=5, help="runs per measurement; medians (default 5)")
    bench.add_argument("--effect-frames", type=frames, default=300, help="frames per effect measurement")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    return parser


def _press(args, sensor) -> None:
    contact = press_contact(args.x_mm, args.y_mm, args.depth_mm, args.shape, args.radius_mm, args.shear_x_mm,
                            args.shear_y_mm, args.friction)
    report = press_report(sensor, contact, ground_truth_model(sensor, args.model))
    if args.json:
        print(json.dumps(report))
        return
    fx, fy, fz = report["total_force_n"]
    print(f"{sensor.name}: {args.shape} at ({args.x_mm}, {args.y_mm}) mm, {args.depth_mm} mm deep "
          f"({report['model']} model)\n  total force fx {fx:+.4f} N, fy {fy:+.4f} N, fz {fz:+.4f} N over "
          f"{report['loaded_bins']} of {report['rows'] * report['cols']} bins")


def _generate(args, sensor) -> None:
    from tactile_sim.simulator import Simulator

    scene = load_scene(args.scene, sensor)  # a bad scene is reported before the simulator is built (~1 s)
    sim = Simulator(sensor, ground_truth=args.model)
    out = write_dataset(sim, scene, args.out, progress=not args.no_progress, frames=args.frames,
                        overwrite=args.overwrite)
    print(f"wrote {len(scene) if args.frames is None else min(args.frames, len(scene))} frames of scene "
          f"{scene.name!r} to {out}")


def _render(args, sensor) -> None:
    from tactile_sim.preview import write_previews
    from tactile_sim.simulator import Simulator

    scene = load_scene(args.scene, sensor)
    paths = write_previews(Simulator(sensor, ground_truth=args.model), scene, args.out, count=args.count,
                           frames=args.frames)
    print("\n".join(str(p) for p in paths))


def _bench(args, sensor) -> None:
    from tactile_sim.bench import run_benchmark

    result = run_benchmark(sensor, scene=args.scene, frames=args.frames, runs=args.runs,
                           effect_frames=args.effect_frames)
    if args.json:
        print(json.dumps(result))
        return
    print(f"{result['sensor']}, {result['cameras']} cameras, {result['frames']} frames of {result['scene']}: "
          f"{result['frames_per_second']:.0f} frames/s ({result['frames_per_cpu_second']:.0f} per CPU second)")
    for name, ms in result["effect_ms"].items():
        print(f"  {name:22s} {ms:+.3f} ms per frame")


@stops_quietly_on_closed_pipe
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with stop_signals_raised():
            sensor = load_sensor(args.sensor)
            {"press": _press, "generate": _generate, "render": _render, "bench": _bench}[args.command](args, sensor)
    except (SceneError, DatasetError, SensorConfigError, ValueError) as exc:
        return error_exit(f"tactile-sim {args.command}", exc)
    except BrokenPipeError:
        raise  # the reader went away: stops_quietly_on_closed_pipe ends the command as a shell tool does
    except StopSignal as stop:  # Ctrl-C or SIGTERM: one line and the shell's status for it, not a traceback
        stopped = "; the data set is left marked incomplete" if args.command == "generate" else ""
        print(f"tactile-sim {args.command}: stopped by {stop.named}{stopped}", file=sys.stderr)
        return stop.exit_status
    except OSError as exc:  # a file or directory that cannot be read or written (--out /dev/null/x, a full disk)
        problem = f"{exc.strerror or exc}: {exc.filename}" if exc.filename else exc
        return error_exit(f"tactile-sim {args.command}", problem)
    return 0


if __name__ == "__main__":
    sys.exit(main())
