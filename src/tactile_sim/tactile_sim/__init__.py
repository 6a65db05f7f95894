"""The simulated tactile sensor: contact mechanics, gel, particles, cameras and scene effects (no ROS import).

    from tactile_description import load_sensor
    from tactile_sim import Simulator, load_scene, open_dataset, write_dataset
    sim = Simulator(load_sensor())
    for frame in sim.stream(load_scene("paper_grid")): ...

docs/simulator.md describes the scenes, the effects and the data set format.
"""

from tactile_sim.dataset import Dataset, DatasetError, open_dataset, write_dataset
from tactile_sim.effects import SceneError
from tactile_sim.scene import Scene, load_scene
from tactile_sim.simulator import Frame, Simulator

__all__ = ["Dataset", "DatasetError", "Frame", "Scene", "SceneError", "Simulator", "load_scene", "open_dataset",
           "write_dataset"]
