"""The simulator's speed, as one JSON object (`tactile-sim bench --json`).

- frames_per_second: frames of every camera with their ground truth, streamed from the default scene's presses
  (its rest frames are left out: they cost nothing), with the scene's own effects (light sensor noise). Median
  over `runs` runs of wall-clock time, on one CPU core (the process is pinned to one core where the OS allows).
  frames_per_cpu_second is the same from the process's CPU time, which a machine shared with other jobs
  disturbs less.
- stage_ms: median ms per frame of each stage (ground truth, particle displacement, rendering, effects and
  quantisation) over the same frames.
- effect_ms: extra ms per frame of each effect when a scene names it alone, against the same frames with no
  effect. The two streams advance in lockstep, frame by frame (which goes first alternates), and the median of
  the per-frame differences is taken, then the median over runs: pairing frames keeps a slow moment of a
  shared machine from landing on one side only. unnamed_effects_ms pairs the stream without effects with the
  bare pipeline calls (ground truth, render, quantise): what the effect machinery costs when a scene names
  nothing (~0: an unnamed effect does no work, so it may come out slightly below 0, a difference of timing noise).
  effect_apply_ms times each effect's own call alone.
- ground_truth: each ground-truth model's cost (contact.benchmark_models).
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from tactile_description import SensorDescription
from tactile_sim.contact import benchmark_models
from tactile_sim.effects import EFFECTS, bind_effects, parse_effect
from tactile_sim.scene import Scene, load_scene
from tactile_sim.simulator import Simulator, quantize

#: The parameters each effect is benchmarked with (the defaults, plus the cameras a dropout needs).
EFFECT_SETTINGS = {
    "sensor_noise": {"sigma": 1.0},
    "defocus_blur": {"sigma_px": 1.0},
    "illumination_drift": {"amplitude": 0.1, "period_s": 10.0},
    "led_flicker": {"amplitude": 0.05},
    "exposure_saturation": {"gain": 2.0},
    "camera_dropout": {"mode": "frozen"},
    "reference_drift": {"creep_px_per_s": [0.5, 0.0], "dimming_per_s": 0.01},
    "camera_misalignment": {"shift_px": [1.0, 0.5], "rotation_deg": 1.0},
}


def pin_to_one_core() -> list[int] | None:
    """Restrict this process to one CPU (the last it may use); returns the affinity, None where unsupported."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    core = max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return sorted(os.sched_getaffinity(0))


def presses_only(scene: Scene) -> Scene:
    """The scene without its rest segments (frames without contact cost only a copy of the reference)."""
    segments = tuple(s for s in scene.segments if s.kind != "rest")
    return dataclasses.replace(scene, segments=segments or scene.segments)


def _time_stream(sim: Simulator, scene: Scene) -> tuple[float, float]:
    """(wall s, CPU s) to stream every frame of `scene`."""
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in sim.stream(scene):
        pass
    return time.perf_counter() - wall, time.process_time() - cpu


def _bare_frames(sim: Simulator, scene: Scene):
    """The pipeline calls alone (ground truth, render, quantise), no stream or effect machinery."""
    for contacts in scene.contacts(sim.sensor):
        yield quantize(sim.render(sim.bin_forces(contacts)))


def _paired_ms(baseline, candidate, n: int) -> float:
    """Median over n frames of (time of candidate's next frame - time of baseline's next frame), in ms."""
    differences = []
    for index in range(n):
        first, second = (baseline, candidate) if index % 2 == 0 else (candidate, baseline)
        t0 = time.perf_counter()
        next(first)
        t1 = time.perf_counter()
        next(second)
        t2 = time.perf_counter()
        baseline_s, candidate_s = (t1 - t0, t2 - t1) if index % 2 == 0 else (t2 - t1, t1 - t0)
        differences.append(candidate_s - baseline_s)
    return 1e3 * float(np.median(differences))


def _effect_apply_ms(sim: Simulator, scene: Scene, repeats: int = 200) -> float:
    """Median ms of one call of the scene's effect chain on a rendered frame (images, then transport)."""
    effects = bind_effects(scene.effects, scene.effect_context(sim.sensor))
    contacts = next(iter(scene.contacts(sim.sensor)))
    clean = sim.render(sim.bin_forces(contacts))
    times = []
    for index in range(repeats):
        images = clean.copy()
        start = time.perf_counter()
        effects.apply_images(images, index, index / sim.sensor.frame_rate_hz)
        effects.apply_transport(quantize(images), np.ones(sim.sensor.n_cameras, bool), index)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def _stage_ms(sim: Simulator, scene: Scene) -> dict:
    effects = bind_effects(scene.effects, scene.effect_context(sim.sensor))
    times = {"ground_truth": [], "displacement": [], "render": [], "effects_and_quantise": []}
    for index, contacts in enumerate(scene.contacts(sim.sensor)):
        t0 = time.perf_counter()
        forces = sim.bin_forces(contacts)
        t1 = time.perf_counter()
        displacements = sim.gel.displacements_m(forces)
        t2 = time.perf_counter()
        images = sim.renderer.render_displaced(displacements)
        t3 = time.perf_counter()
        effects.apply_images(images, index, 0.0)
        quantize(images)
        t4 = time.perf_counter()
        for key, value in zip(times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3), strict=True):
            times[key].append(value)
    return {key: 1e3 * float(np.median(values)) for key, values in times.items()}


def _with_effects(scene: Scene, nodes: list[dict]) -> Scene:
    return dataclasses.replace(scene, effects=tuple(parse_effect(n, "benchmark") for n in nodes))


def run_benchmark(sensor: SensorDescription | None = None, scene: str = "paper_grid", frames: int | None = None,
                  runs: int = 5, effect_frames: int = 300, pin: bool = True) -> dict:
    """Measure the simulator (see the module docstring); `frames` limits the main measurement (None: all)."""
    affinity = pin_to_one_core() if pin else None
    sim = Simulator(sensor)
    main = presses_only(load_scene(scene, sim.sensor))
    if frames is not None:
        main = main.limited(frames)
    for _ in sim.stream(main.limited(min(20, len(main)))):  # warm-up: caches, allocator
        pass
    walls, cpus = [], []
    for _ in range(runs):
        wall, cpu = _time_stream(sim, main)
        walls.append(wall)
        cpus.append(cpu)
    n = len(main)

    short = main.limited(min(effect_frames, len(main)))
    baseline = _with_effects(short, [])
    configs = {name: _with_effects(short, [dict(EFFECT_SETTINGS[name], type=name,
                                                **({"cameras": [sim.camera_ids[0]]} if name == "camera_dropout"
                                                   else {}))])
               for name in EFFECTS}
    per_run: dict[str, list[float]] = {name: [] for name in ["unnamed", *configs]}
    n_short = len(short)
    for _ in range(runs):
        per_run["unnamed"].append(_paired_ms(_bare_frames(sim, short), sim.stream(baseline), n_short))
        for name, config in configs.items():
            per_run[name].append(_paired_ms(sim.stream(baseline), sim.stream(config), n_short))
    ms = {name: float(np.median(values)) for name, values in per_run.items()}
    return {
        "sensor": sim.sensor.name,
        "cameras": sim.sensor.n_cameras,
        "scene": main.name,
        "frames": n,
        "runs": runs,
        "cpu_affinity": affinity,
        "frames_per_second": n / float(np.median(walls)),
        "frames_per_cpu_second": n / float(np.median(cpus)),
        "ms_per_frame": 1e3 * float(np.median(walls)) / n,
        "stage_ms": _stage_ms(sim, short),
        "effect_frames": len(short),
        "effect_ms": {name: ms[name] for name in configs},
        "unnamed_effects_ms": ms["unnamed"],
        "effect_apply_ms": {name: _effect_apply_ms(sim, config) - _effect_apply_ms(sim, baseline)
                            for name, config in configs.items()},
        "ground_truth": benchmark_models(sim.sensor),
    }
